"""Loading Aravis 0.8 through PyGObject, and the few C calls made through ctypes.

``load_aravis()`` imports ``gi.repository.Aravis`` (typelib from Debian's ``gir1.2-aravis-0.8``, PyGObject from
PyPI ``PyGObject<3.51`` -- 3.51+ needs girepository-2.0, which bookworm lacks), or raises ``AravisUnavailable``
saying what to install. ``copy_image`` copies a buffer's image into a new writable numpy array in one memmove
(PyGObject's ``get_image_data`` would make a bytes copy that numpy can only wrap read-only).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import warnings
from types import ModuleType
from typing import Any

import numpy as np
import numpy.typing as npt

ARAVIS_VERSION = "0.8"
LIBARAVIS = "libaravis-0.8.so.0"
INSTALL_HINT = ("install the Debian packages gir1.2-aravis-0.8 (and aravis-tools-cli for arv-tool-0.8) and "
                "'PyGObject<3.51' in the venv: bash scripts/install-system-deps.sh, then scripts/install.sh")


class AravisUnavailable(ImportError):
    """Aravis or PyGObject cannot be loaded; the message says which and what to install."""


_loaded: tuple[ModuleType, ModuleType] | None = None


def load_aravis() -> tuple[ModuleType, ModuleType]:
    """``(Aravis, GLib)`` from gi.repository, imported once."""
    global _loaded
    if _loaded is not None:
        return _loaded
    try:
        import gi
    except ImportError as exc:
        raise AravisUnavailable(f"PyGObject (gi) is not installed: {exc}; {INSTALL_HINT}") from exc
    try:
        with warnings.catch_warnings():
            # Only PyGObject's own deprecation notices (e.g. about girepository-1.0 on newer releases); anything
            # else still reaches the caller's filters.
            warnings.filterwarnings("ignore", category=gi.PyGIDeprecationWarning)
            gi.require_version("Aravis", ARAVIS_VERSION)
            from gi.repository import Aravis, GLib
    except (ImportError, ValueError) as exc:
        raise AravisUnavailable(f"Aravis {ARAVIS_VERSION} introspection data cannot be loaded: {exc}; "
                                f"{INSTALL_HINT}") from exc
    _loaded = (Aravis, GLib)
    return _loaded


# ---------------------------------------------------------------------------------------------- ctypes
_lib: ctypes.CDLL | None = None
_capsule_pointer = ctypes.pythonapi.PyCapsule_GetPointer
_capsule_pointer.restype = ctypes.c_void_p
_capsule_pointer.argtypes = [ctypes.py_object, ctypes.c_char_p]


def libaravis() -> ctypes.CDLL:
    """libaravis-0.8 for ctypes, with the signatures livetrack uses declared."""
    global _lib
    if _lib is None:
        name = ctypes.util.find_library("aravis-0.8") or LIBARAVIS
        try:
            lib = ctypes.CDLL(name)
        except OSError as exc:
            raise AravisUnavailable(f"cannot load {name}: {exc}; {INSTALL_HINT}") from exc
        lib.arv_buffer_get_image_data.restype = ctypes.c_void_p
        lib.arv_buffer_get_image_data.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
        lib.arv_buffer_get_data.restype = ctypes.c_void_p
        lib.arv_buffer_get_data.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
        lib.arv_buffer_get_image_width.restype = ctypes.c_int
        lib.arv_buffer_get_image_width.argtypes = [ctypes.c_void_p]
        lib.arv_buffer_get_image_height.restype = ctypes.c_int
        lib.arv_buffer_get_image_height.argtypes = [ctypes.c_void_p]
        _lib = lib
    return _lib


def gobject_pointer(obj: Any) -> int:
    """The C address of a PyGObject-wrapped GObject (valid while ``obj`` lives)."""
    pointer = _capsule_pointer(obj.__gpointer__, None)
    if not pointer:
        raise ValueError(f"{obj!r} has no GObject pointer")
    return int(pointer)


def copy_image(buffer: Any, width: int, height: int, dtype: np.dtype) -> npt.NDArray[np.unsignedinteger]:
    """A writable (height, width) copy of the image in ArvBuffer ``buffer``; ValueError if it is too short."""
    size = ctypes.c_size_t()
    data = libaravis().arv_buffer_get_image_data(gobject_pointer(buffer), ctypes.byref(size))
    image = np.empty((height, width), dtype=dtype)
    if not data or size.value < image.nbytes:
        raise ValueError(f"buffer holds {size.value} bytes, a {width}x{height} {np.dtype(dtype).name} image needs "
                         f"{image.nbytes}")
    ctypes.memmove(image.ctypes.data, data, image.nbytes)
    return image
