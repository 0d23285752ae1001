"""The data shipped inside the package (``metrology/data/``): the demo's measured run, a run
hiding an effect, the datum cloud, the paper's layouts and a curved panel.

They are regenerated, byte for byte, by the seeded scripts in the repository's ``fixtures/``;
an installed metro reads them from here, so ``metro demo`` runs from any folder.
"""

from __future__ import annotations

from pathlib import Path

#: the folder of the bundled data (inside the installed package)
DATA_DIR = Path(__file__).resolve().parents[1] / "data"


def data_path(*parts: str) -> Path:
    """The bundled file or folder ``metrology/data/<parts>``; ``FileNotFoundError`` naming it
    when the installation lacks it."""
    p = DATA_DIR.joinpath(*parts)
    if not p.exists():
        raise FileNotFoundError(f"{p}: bundled data missing (reinstall metro)")
    return p
