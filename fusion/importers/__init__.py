"""Importers that turn real datasets into recording directories (``shearer-recording/1``).

Each importer maps the dataset's sensor axes into the recording's body frame (x right,
y forward, z up), puts its samples on one clock, writes the reference trajectory as
``truth.csv`` and the position fixes as ``position.csv``, and handles the dataset's quirks
explicitly: every choice is a sentence of the returned :class:`ImportReport` and of
``meta.yaml`` ``extra.import_notes``. The written directory is read back through the format
validator before the importer returns.

========================  ==============================  ====================================
kind                      source                          module
========================  ==============================  ====================================
``rtklib-drive``          the dataset folder              :mod:`fusion.importers.rtklib_drive`
``broad``                 one trial's ``.mat`` file       :mod:`fusion.importers.broad`
``pyshoe``                one trial's ``.mat`` file       :mod:`fusion.importers.pyshoe`
========================  ==============================  ====================================

The datasets themselves are not part of the project: :func:`datasets_root` finds them in
``$FUSION_DATASETS`` or next to the repository (``../shared/datasets``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from fusion.importers.broad import import_broad
from fusion.importers.common import DatasetError, ImportReport, datasets_root
from fusion.importers.pyshoe import import_pyshoe, read_pyshoe_labels
from fusion.importers.rtklib_drive import import_rtklib_drive

__all__ = [
    "IMPORTERS",
    "DatasetError",
    "ImportReport",
    "datasets_root",
    "import_broad",
    "import_dataset",
    "import_pyshoe",
    "import_rtklib_drive",
    "read_pyshoe_labels",
]

IMPORTERS: dict[str, Callable[..., ImportReport]] = {
    "rtklib-drive": import_rtklib_drive,
    "broad": import_broad,
    "pyshoe": import_pyshoe,
}
"""Importer of each dataset kind."""


def import_dataset(kind: str, src: str | Path, out: str | Path, **options: Any) -> ImportReport:
    """Import a dataset of ``kind`` from ``src`` into the recording directory ``out``.

    Raises
    ------
    DatasetError
        Unknown kind, missing source, or a source that is not the dataset it claims to be.
    """
    if kind not in IMPORTERS:
        raise DatasetError(f"unknown dataset kind {kind!r}; known: {', '.join(IMPORTERS)}")
    if not Path(src).exists():
        raise DatasetError(f"{src}: no such file or folder (source of a {kind} import)")
    return IMPORTERS[kind](src, out, **options)
