"""MuJoCo without OpenGL for simulation, and the off-screen OpenGL back-end chosen when first asked.

Simulation needs no OpenGL. ``import mujoco`` however picks its GL back-end from ``MUJOCO_GL`` at
import (``mujoco.rendering.classic.gl_context``): with ``MUJOCO_GL=osmesa`` and no system libOSMesa
the import itself fails (``AttributeError: 'NoneType' object has no attribute 'glGetError'``), and
an unknown value (``MUJOCO_GL=bogus``) raises. :func:`import_mujoco` therefore imports mujoco with
``MUJOCO_GL=disable`` for the duration of the import and restores the user's value afterwards, so
importing softsbi, simulating, fitting point clouds and the demo never load an OpenGL library.

Rendering calls :func:`gl_context_class`, which chooses the back-end then:
``MUJOCO_GL`` if set (``osmesa`` or ``egl``); else OSMesa if its library is found (CPU, the
system package ``libosmesa6``); else EGL (GPU drivers, or Mesa's software EGL). When none works
it raises :class:`~softsbi.core.errors.RenderingUnavailable` naming the fix. PyOpenGL fixes its
platform (``PYOPENGL_PLATFORM``) at its first import, so one process renders with one back-end.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import importlib
import os
import sys
from typing import Any

from softsbi.core.errors import EnvironmentFault, RenderingUnavailable

#: GL back-ends softsbi can render with off-screen (no display)
RENDER_BACKENDS = ("osmesa", "egl")
#: what a user can do when no back-end works
RENDER_FIX = ("install OSMesa (`apt-get install -y libosmesa6`, CPU rendering) or use a GPU's EGL "
              "(`MUJOCO_GL=egl`)")

_chosen: dict[str, Any] = {}


def import_mujoco() -> Any:
    """The ``mujoco`` module, imported without loading any OpenGL library.

    Returns:
        the module (already imported ones are returned as they are).

    Raises:
        EnvironmentFault: the MuJoCo package itself cannot be loaded (missing or broken install);
            the message names the fix. Not a failed simulation: a fit stops without storing it.
    """
    mod = sys.modules.get("mujoco")
    if mod is not None:
        return mod
    had = "MUJOCO_GL" in os.environ
    saved = os.environ.get("MUJOCO_GL")
    os.environ["MUJOCO_GL"] = "disable"
    try:
        import mujoco  # engine: imported once with MUJOCO_GL set for this process
    except Exception as exc:
        raise EnvironmentFault(f"MuJoCo cannot be loaded ({type(exc).__name__}: {exc}); reinstall it with "
                               f"`pip install --force-reinstall mujoco`") from exc
    finally:
        if had:
            os.environ["MUJOCO_GL"] = saved  # type: ignore[assignment]
        else:
            os.environ.pop("MUJOCO_GL", None)
    return mujoco


def _library_loads(*names: str) -> bool:
    """Whether one of the shared libraries ``names`` (as for :func:`ctypes.util.find_library`) loads."""
    for name in names:
        path = ctypes.util.find_library(name)
        if not path:
            continue
        try:
            ctypes.CDLL(path)
            return True
        except OSError:
            continue
    return False


def choose_backend() -> str:
    """The off-screen GL back-end to render with: ``MUJOCO_GL`` if set, else ``osmesa`` when
    libOSMesa loads, else ``egl`` when libEGL loads.

    Raises:
        RenderingUnavailable: ``MUJOCO_GL`` names a back-end softsbi cannot render with off-screen,
            or no back-end's library loads.
    """
    want = os.environ.get("MUJOCO_GL", "").strip().lower()
    if want:
        if want not in RENDER_BACKENDS:
            raise RenderingUnavailable(f"MUJOCO_GL={want!r} is not an off-screen OpenGL back-end softsbi can render "
                                       f"with; set MUJOCO_GL=osmesa or MUJOCO_GL=egl, or unset it to choose "
                                       f"automatically")
        return want
    if _library_loads("OSMesa"):
        return "osmesa"
    if _library_loads("EGL"):
        return "egl"
    raise RenderingUnavailable(f"rendering needs off-screen OpenGL and neither libOSMesa nor libEGL can be loaded; "
                               f"{RENDER_FIX}. Simulation and point-cloud fits need no OpenGL")


def gl_context_class() -> Any:
    """MuJoCo's ``GLContext`` class of the chosen back-end (:func:`choose_backend`), loaded once.

    Raises:
        RenderingUnavailable: the back-end's library cannot be loaded or PyOpenGL was already set up
            for another platform in this process; the message names the back-end and the fix.
    """
    backend = choose_backend()
    if backend in _chosen:
        return _chosen[backend]
    import_mujoco()
    platform = os.environ.get("PYOPENGL_PLATFORM", "").strip().lower()
    if platform and platform != backend and "OpenGL" in sys.modules:
        raise RenderingUnavailable(f"PyOpenGL is already set up for {platform!r} in this process, so MuJoCo cannot "
                                   f"render with {backend!r}; set MUJOCO_GL={platform} or start a new process")
    try:
        cls = importlib.import_module(f"mujoco.{backend}").GLContext
    except Exception as exc:
        raise RenderingUnavailable(f"off-screen OpenGL back-end {backend!r} cannot be loaded "
                                   f"({type(exc).__name__}: {exc}); {RENDER_FIX}") from exc
    _chosen[backend] = cls
    return cls
