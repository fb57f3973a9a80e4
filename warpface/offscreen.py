"""Choosing PyOpenGL's offscreen back end before anything imports OpenGL: EGL when it works, else OSMesa.

pyrender renders offscreen through EGL (a GPU driver, or Mesa's software EGL from ``libegl1``) or
OSMesa (``libosmesa6``). pyrender pins PyOpenGL 3.1.0, whose OSMesa binding lacks
``OSMesaCreateContextAttribs`` (pyrender needs it); its EGL binding works. So a plain
``pip install warpface`` renders through EGL, and OSMesa is used only where EGL cannot start and
PyOpenGL ≥ 3.1.5 is installed. The choice goes to ``PYOPENGL_PLATFORM`` (a value already set is
kept) and must be made before ``OpenGL`` is first imported: PyOpenGL fixes its platform then.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from functools import lru_cache

from .errors import OffscreenUnavailable

__all__ = ["OffscreenUnavailable", "choose_platform", "egl_works", "osmesa_usable", "INSTALL_HINT"]

INSTALL_HINT = (
    "install the system GL libraries (Debian/Ubuntu: sudo apt install libegl1 libgl1; "
    "or libosmesa6 with pip install 'PyOpenGL>=3.1.7')"
)


@lru_cache(maxsize=1)
def egl_works() -> bool:
    """True when an EGL display can be initialised the way pyrender does it (first EGL device, else the
    default display), probed with ctypes so PyOpenGL's platform stays unchosen."""
    name = ctypes.util.find_library("EGL") or "libEGL.so.1"
    try:
        egl = ctypes.CDLL(name)
    except OSError:
        return False
    egl.eglGetProcAddress.restype = ctypes.c_void_p
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    egl.eglGetDisplay.restype = ctypes.c_void_p
    egl.eglGetDisplay.argtypes = [ctypes.c_void_p]
    egl.eglInitialize.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_int), ctypes.POINTER(ctypes.c_int)]
    egl.eglTerminate.argtypes = [ctypes.c_void_p]
    display = None
    query_address = egl.eglGetProcAddress(b"eglQueryDevicesEXT")
    platform_address = egl.eglGetProcAddress(b"eglGetPlatformDisplayEXT")
    if query_address and platform_address:
        query = ctypes.CFUNCTYPE(
            ctypes.c_uint, ctypes.c_int, ctypes.POINTER(ctypes.c_void_p), ctypes.POINTER(ctypes.c_int)
        )(query_address)
        platform_display = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p)(
            platform_address
        )
        devices, count = (ctypes.c_void_p * 1)(), ctypes.c_int(0)
        if query(1, devices, ctypes.byref(count)) and count.value > 0:
            display = platform_display(0x313F, devices[0], None)  # EGL_PLATFORM_DEVICE_EXT
    if not display:
        display = egl.eglGetDisplay(None)  # EGL_DEFAULT_DISPLAY
    if not display:
        return False
    major, minor = ctypes.c_int(0), ctypes.c_int(0)
    if not egl.eglInitialize(display, ctypes.byref(major), ctypes.byref(minor)):
        return False
    egl.eglTerminate(display)
    return True


def osmesa_usable() -> bool:
    """True when libOSMesa is installed and PyOpenGL is new enough (≥ 3.1.5) for pyrender's OSMesa back end."""
    if not (ctypes.util.find_library("OSMesa") or _loads("libOSMesa.so.8")):
        return False
    try:
        from importlib.metadata import version

        parts = tuple(int(p) for p in version("PyOpenGL").split(".")[:3] if p.isdigit())
    except Exception:  # noqa: BLE001 — no metadata: cannot tell, do not pick it
        return False
    return parts >= (3, 1, 5)


def _loads(name: str) -> bool:
    try:
        ctypes.CDLL(name)
    except OSError:
        return False
    return True


def choose_platform() -> str:
    """Set ``PYOPENGL_PLATFORM`` to a working offscreen back end (unless already set) and return it.

    Raises:
        OffscreenUnavailable: neither EGL nor OSMesa can be used; the message names what to install.
    """
    chosen = os.environ.get("PYOPENGL_PLATFORM")
    if chosen:
        return chosen
    if "OpenGL.platform" in sys.modules:  # too late to choose: PyOpenGL has picked already
        return type(sys.modules["OpenGL.platform"].PLATFORM).__name__
    if egl_works():
        chosen = "egl"
    elif osmesa_usable():
        chosen = "osmesa"
    else:
        raise OffscreenUnavailable(
            f"offscreen rendering needs OpenGL through EGL or OSMesa, and neither works here: {INSTALL_HINT}"
        )
    os.environ["PYOPENGL_PLATFORM"] = chosen
    return chosen
