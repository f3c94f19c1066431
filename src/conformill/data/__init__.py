"""Sample meshes shipped with conformill (see ``SAMPLES.md`` beside this file).

Read one with ``conformill.read_mesh("sample:face")`` or on the command line with
``conformill param sample:face ...``. The files are binary PLY in mm, faces wound
counter-clockwise seen from +Z (the tool axis), lowest point at ``z = 0``, centred in XY.
They are rebuilt deterministically by ``tools/make_samples.py``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from conformill.errors import MeshError

#: sample name -> one-line description
SAMPLES: dict[str, str] = {
    "face": "human face (Choi & Lui 2015 example mesh, Apache-2.0), ~120 mm wide, decimated scan-like mesh",
    "lion": "Chinese lion head relief (Choi & Lui 2015 example mesh, Apache-2.0), ~120 mm, deep undercuts: a stress sample",
    "patch": "CAD-like free-form patch, 120 x 80 mm, non-convex curved outline, relief ~22 mm, generated",
}


def sample_path(name: str) -> Path:
    """File of the sample ``name`` (a key of :data:`SAMPLES`).

    Raises
    ------
    MeshError
        Unknown name (the message lists the samples) or the file is missing from the
        installation.
    """
    if name not in SAMPLES:
        known = ", ".join(sorted(SAMPLES))
        raise MeshError(f"sample:{name}: unknown sample; available: {known}")
    ref = resources.files(__name__).joinpath(f"{name}.ply")
    path = Path(str(ref))
    if not path.is_file():
        raise MeshError(f"sample:{name}: the sample file {path} is missing from the installation")
    return path
