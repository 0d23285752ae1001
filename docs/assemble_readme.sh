#!/usr/bin/env bash
# README.md is assembled from the sections in docs/ (edit those, then run this).
set -euo pipefail
cd "$(dirname "$0")/.."
{
  for part in head core fit_plane calibrate normals diagnose tail; do
    cat "docs/readme_${part}.md"
    echo
  done
} > README.md.tmp && mv README.md.tmp README.md
