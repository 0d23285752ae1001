"""Fixtures of the diagnosis tests."""

from __future__ import annotations

import pytest


@pytest.fixture
def adequacy_spy(monkeypatch):
    """Record each call of ``select.adequate_member`` as ``(member held, held consistent,
    member returned, returned consistent, its parameters minus the held's, labels of the causes
    given)``; returns the list."""
    import metrology.diagnosis.select as select
    from metrology.diagnosis.members import _consistent

    seen = []
    adequate = select.adequate_member

    def spy(sc, ref, held, *args, **kw):
        out = adequate(sc, ref, held, *args, **kw)
        seen.append((held.label, _consistent(sc.ds, sc.b, held), out.label, _consistent(sc.ds, sc.b, out),
                     out.n_params - held.n_params, tuple(g.label for g in ref.given)))
        return out

    monkeypatch.setattr(select, "adequate_member", spy)
    return seen
