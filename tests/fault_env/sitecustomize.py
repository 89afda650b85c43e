"""Test helper (tests/test_no_gl.py): on PYTHONPATH, makes this interpreter and its subprocesses
behave like a fresh machine with parts of the environment missing.

``SOFTSBI_TEST_BLOCK`` (comma-separated, default ``gl``):
* ``gl``: every attempt to load an OpenGL library through ctypes fails (no libOSMesa, libEGL, libGL);
* ``mujoco``: ``import mujoco`` fails, as with a broken MuJoCo install.
"""
import ctypes
import ctypes.util
import importlib.abc
import os
import re
import sys

_BLOCK = {b.strip() for b in os.environ.get("SOFTSBI_TEST_BLOCK", "gl").split(",") if b.strip()}

if "gl" in _BLOCK:
    _GL = re.compile(r"(osmesa|egl|libgl|glx|glesv|opengl)", re.IGNORECASE)
    _cdll_init = ctypes.CDLL.__init__
    _find_library = ctypes.util.find_library

    def _refusing_init(self, name, *args, **kwargs):
        if name and _GL.search(str(name)):
            raise OSError(f"{name}: cannot open shared object file (blocked: no OpenGL on this machine)")
        _cdll_init(self, name, *args, **kwargs)

    def _refusing_find(name):
        return None if _GL.search(name) else _find_library(name)

    ctypes.CDLL.__init__ = _refusing_init
    ctypes.util.find_library = _refusing_find

if "mujoco" in _BLOCK:
    class _NoMujoco(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "mujoco" or name.startswith("mujoco."):
                raise ImportError("libmujoco.so.4.0.0: cannot open shared object file (blocked by the test)")
            return None

    sys.meta_path.insert(0, _NoMujoco())
