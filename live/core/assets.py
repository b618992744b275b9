"""Where livecap's files are: one locator for every asset.

Shipped files (model weights, the body library, the demo session, suit layouts) are package data,
found through ``importlib.resources`` so an installed wheel works outside a checkout. The shared
recordings and clips (``../shared/data`` beside a checkout, or ``$LIVECAP_SHARED_DATA``) and the
cache (``.cache`` in a checkout, else ``$LIVECAP_CACHE`` or ``~/.cache/livecap``) are found here too.
"""

from __future__ import annotations

import os
from importlib.resources import files
from pathlib import Path


def _package_dir(package: str, *parts: str) -> Path:
    # Packages are installed as plain directories (no zipped eggs), so the traversable is a path.
    return Path(str(files(package).joinpath(*parts)))


def weights_dir() -> Path:
    """The shipped ONNX models and their model cards."""
    return _package_dir("models", "weights")


def weight(name: str) -> Path:
    """One shipped model file, e.g. ``weight("skeleton.onnx")``."""
    return weights_dir() / name


def bodies_dir() -> Path:
    """The body library: one ``.npz`` per preset and ``library.json``."""
    return _package_dir("models", "bodies")


def demo_session() -> Path:
    """The bundled session that ``livecap demo`` replays."""
    return _package_dir("sim", "data", "demo.mcap")


def layouts_dir() -> Path:
    """The shipped suit layouts (JSON)."""
    return _package_dir("drivers", "layouts")


def checkout_root() -> Path | None:
    """The repository root when running from a checkout, else None."""
    root = Path(__file__).resolve().parents[2]
    return root if (root / "pyproject.toml").is_file() else None


def shared_data_dir() -> Path:
    """The shared data (CMU clips, real recordings): ``$LIVECAP_SHARED_DATA``, else
    ``../shared/data`` beside the checkout."""
    env = os.environ.get("LIVECAP_SHARED_DATA")
    if env:
        return Path(env)
    root = checkout_root()
    return (root.parent if root is not None else Path.cwd()) / "shared" / "data"


def bvh_dir() -> Path:
    """The shared CMU motion-capture clips."""
    return shared_data_dir() / "bvh"


def cache_dir(*parts: str) -> Path:
    """A cache folder (not created): ``.cache`` in a checkout, else ``$LIVECAP_CACHE`` or
    ``~/.cache/livecap``."""
    env = os.environ.get("LIVECAP_CACHE")
    root = checkout_root()
    if env:
        base = Path(env)
    elif root is not None:
        base = root / ".cache"
    else:
        base = Path.home() / ".cache" / "livecap"
    return base.joinpath(*parts)
