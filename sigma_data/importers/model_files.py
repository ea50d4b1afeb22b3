"""Which files an imported demo's MJCF may make MuJoCo read: robosuite's own assets, unless the file is trusted.

An HDF5 demo carries its scene as MJCF text (``attrs["model_file"]``). robosuite's ``edit_model_xml`` only
rewrites mesh and texture paths that contain a ``robosuite`` directory, so a crafted file can still point MuJoCo
at any readable file: an ``<include file="/abs/path.xml"/>``, an absolute mesh or texture path, a path that climbs
out of the package (``.../robosuite/../../x``), or a relative path under a ``<compiler meshdir=...>`` elsewhere --
and the file's
content would end up rendered into the dataset. :func:`foreign_files` lists every such reference; the importer
refuses the demo unless ``--trust_model_files=true``.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path

# Elements whose ``file`` attribute MuJoCo reads, and the compiler attributes that redirect relative paths.
COMPILER_DIRS = ("meshdir", "texturedir", "assetdir")
DIR_OF = {"mesh": "meshdir", "skin": "meshdir", "texture": "texturedir", "hfield": "texturedir"}


def asset_roots() -> list[Path]:
    """Directories a demo's model may read from: the installed robosuite package (and robosuite_models, if
    installed), symlinks resolved."""
    import robosuite

    roots = [Path(robosuite.__file__).resolve().parent]
    try:
        import robosuite_models

        roots.append(Path(robosuite_models.__file__).resolve().parent)
    except ImportError:
        pass
    return roots


def _inside(path: Path, roots: list[Path]) -> bool:
    real = Path(os.path.realpath(path))
    return any(real == root or root in real.parents for root in roots)


def foreign_files(xml: str, roots: list[Path] | None = None) -> list[str]:
    """References in MJCF ``xml`` to files outside ``roots`` (default :func:`asset_roots`), as
    ``"<tag file=...>"`` strings; [] when the model reads only robosuite's assets. Raises ``ValueError`` when
    ``xml`` is not XML. Relative paths are resolved as MuJoCo resolves them for a model given as a string: against
    the compiler's directory attributes, else the working directory."""
    roots = asset_roots() if roots is None else [Path(r).resolve() for r in roots]
    try:
        tree = ET.fromstring(xml)
    except ET.ParseError as exc:
        raise ValueError(f"not valid XML ({exc})") from exc
    found: list[str] = []
    dirs: dict[str, str] = {}
    for compiler in tree.iter("compiler"):
        for attr in COMPILER_DIRS:
            if compiler.get(attr) is not None:
                dirs[attr] = compiler.get(attr)  # only matters for the relative paths below, checked there
    for elem in tree.iter():
        name = elem.get("file")
        if name is None:
            continue
        base = dirs.get(DIR_OF.get(elem.tag, "assetdir"), dirs.get("assetdir", ""))
        path = Path(name) if os.path.isabs(name) else Path(os.path.abspath(os.path.join(base, name)))
        if not _inside(path, roots):
            found.append(f"<{elem.tag} file={name!r}>")
    return found
