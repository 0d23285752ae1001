"""Tests of metrology.diagnosis and the effect catalogue it reads."""
