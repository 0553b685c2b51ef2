"""First-hit ray casting against a :class:`~landing_zone.tools.sim.mesh.Mesh` with Embree.

Two back ends, same results (checked in test/test_sim_raycast.py):

* ``'embree'``: Embree 4 called through ``ctypes`` in the library the ``embreex`` wheel ships
  (``embreex.libs/libembree4*.so``). embreex's own mesh constructor copies every vertex and index
  through Python-level indexing (about 1 us per triangle: 0.2 s for one grass patch), creates
  its device with one thread per core (16 worker processes would each start 16 build threads)
  and always uses the high-quality SAH builder. Here the numpy arrays are shared with Embree
  without a copy, the device's thread count is set, and the scene is built with Embree's Morton
  builder (``RTC_SCENE_FLAG_DYNAMIC`` + ``RTC_BUILD_QUALITY_LOW``), 5-10x faster to build, which is
  what matters for single-use scenes that see a few ten thousand rays each. Rays go in packets
  of 16 (``rtcIntersect16``), so the Python loop runs once per 16 rays.
* ``'embreex'``: embreex's Python API (``EmbreeScene.run``), used when the library file cannot be
  found (a wheel laid out differently) or on request.
"""
from __future__ import annotations

import ctypes
import glob
import importlib.util
import os
import threading
from dataclasses import dataclass

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.mesh import NO_RETURN, Mesh

__all__ = ['Hits', 'RayCaster', 'embree_library_path', 'embree_started']

# Embree 4 constants (rtcore_common.h, rtcore_geometry.h, rtcore_scene.h).
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX = 0
_BUFFER_TYPE_VERTEX = 1
_FORMAT_UINT3 = 0x5003
_FORMAT_FLOAT3 = 0x9003
_BUILD_QUALITY_LOW = 0
_SCENE_FLAG_DYNAMIC = 1
_INVALID_ID = 0xFFFFFFFF

# RTCRayHit16 is structure-of-arrays: each field is 16 lanes of 4 bytes (64 bytes). Ray fields
# org_x, org_y, org_z, tnear, dir_x, dir_y, dir_z, time, tfar, mask, id, flags; hit fields
# Ng_x, Ng_y, Ng_z, u, v, primID, geomID, instID[1], instPrimID[1] (21 fields, 1344 bytes).
# Packets are laid out 24 fields apart so that a build with more instance levels still fits.
_F_ORG, _F_TNEAR, _F_DIR, _F_TIME, _F_TFAR, _F_MASK, _F_ID, _F_FLAGS = 0, 3, 4, 7, 8, 9, 10, 11
_F_PRIM, _F_GEOM, _F_INST = 17, 18, 19
_FIELDS = 24
_LANES = 16
_ALIGN = 64


@dataclass
class Hits:
    """What each ray hit first.

    Attributes:
        t: (N,) float64 distance along the (unit) direction to the hit; inf where nothing was hit.
        face: (N,) int64 index of the face hit; -1 where nothing was hit.
        label: (N,) uint8 class of the face hit; NO_RETURN where nothing was hit.
    """

    t: np.ndarray
    face: np.ndarray
    label: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return self.face >= 0


def embree_library_path() -> str | None:
    """Path of the Embree 4 shared library bundled with the embreex wheel, or None."""
    spec = importlib.util.find_spec('embreex')
    if spec is None or not spec.submodule_search_locations:
        return None
    pkg = list(spec.submodule_search_locations)[0]
    site = os.path.dirname(pkg)
    for pattern in ('embreex.libs/libembree4*.so*', 'embreex/.dylibs/libembree4*.dylib',
                    'embreex.libs/embree4*.dll', 'embreex/libembree4*.so*'):
        found = sorted(glob.glob(os.path.join(site, pattern)))
        if found:
            return found[0]
    return None


def embree_started() -> bool:
    """Whether this process has started Embree (a forked child would inherit its threads)."""
    return _Embree.has_devices()


class _Embree:
    """The Embree 4 C API through ctypes, and one device per thread count."""

    _lock = threading.Lock()
    _instance: '_Embree | None' = None
    _failed = False

    def __init__(self, path: str) -> None:
        lib = ctypes.CDLL(path)
        vp, u32, i32, sz = ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_size_t
        for name, res, args in (
                ('rtcNewDevice', vp, [ctypes.c_char_p]),
                ('rtcGetDeviceError', i32, [vp]),
                ('rtcNewScene', vp, [vp]),
                ('rtcSetSceneFlags', None, [vp, i32]),
                ('rtcSetSceneBuildQuality', None, [vp, i32]),
                ('rtcNewGeometry', vp, [vp, i32]),
                ('rtcSetGeometryBuildQuality', None, [vp, i32]),
                ('rtcSetSharedGeometryBuffer', None, [vp, i32, u32, i32, vp, sz, sz, sz]),
                ('rtcCommitGeometry', None, [vp]),
                ('rtcAttachGeometry', u32, [vp, vp]),
                ('rtcReleaseGeometry', None, [vp]),
                ('rtcCommitScene', None, [vp]),
                ('rtcReleaseScene', None, [vp]),
                ('rtcIntersect16', None, [vp, vp, vp, vp])):
            fn = getattr(lib, name)
            fn.restype = res
            fn.argtypes = args
        self.lib = lib
        self.devices: dict[int, int] = {}

    @classmethod
    def get(cls) -> '_Embree | None':
        with cls._lock:
            if cls._instance is None and not cls._failed:
                path = embree_library_path()
                try:
                    cls._instance = cls(path) if path else None
                except (OSError, AttributeError):
                    cls._instance = None
                cls._failed = cls._instance is None
            return cls._instance

    @classmethod
    def has_devices(cls) -> bool:
        """Whether this process has created an Embree device (and with it Embree's threads)."""
        return cls._instance is not None and bool(cls._instance.devices)

    def device(self, threads: int) -> int:
        with self._lock:
            if threads not in self.devices:
                config = f'threads={threads}' if threads > 0 else ''
                dev = self.lib.rtcNewDevice(config.encode())
                if not dev:
                    raise SimulationError('Embree could not create a device')
                self.devices[threads] = dev
            return self.devices[threads]


def _aligned(nbytes: int) -> np.ndarray:
    """A zeroed uint8 buffer whose data pointer is 64-byte aligned (Embree's packets need it)."""
    raw = np.zeros(nbytes + _ALIGN, dtype=np.uint8)
    start = (-raw.ctypes.data) % _ALIGN
    return raw[start:start + nbytes]


class RayCaster:
    """First-hit queries against one static mesh.

    Args:
        mesh: the scene; its arrays are shared with Embree (keep them unchanged).
        threads: Embree build threads; 0 = one per core. Worker processes use 1.
        backend: ``'embree'`` (default, falls back to ``'embreex'`` when the library is not
            found) or ``'embreex'``.
    """

    def __init__(self, mesh: Mesh, threads: int = 0, backend: str = 'embree') -> None:
        if backend not in ('embree', 'embreex'):
            raise SimulationError(f"unknown ray casting backend {backend!r}")
        self.mesh = mesh
        self._labels = mesh.labels
        self._scene = None
        self._embreex = None
        # Embree reads the last vertex as 16 bytes: one padding row keeps that inside the array.
        self._vertices = np.zeros((len(mesh.vertices) + 1, 3), dtype=np.float32)
        self._vertices[:-1] = mesh.vertices
        self._faces = np.ascontiguousarray(mesh.faces, dtype=np.uint32)
        api = _Embree.get() if backend == 'embree' else None
        self.backend = 'embree' if api is not None else 'embreex'
        if not len(self._faces):
            return
        if api is not None:
            self._api = api
            self._device = api.device(threads)
            self._build(api)
        else:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh
            self._embreex = rtcore_scene.EmbreeScene()
            TriangleMesh(self._embreex, self._vertices[:-1], self._faces.astype(np.int32))

    def _build(self, api: _Embree) -> None:
        lib, dev = api.lib, self._device
        scene = lib.rtcNewScene(dev)
        lib.rtcSetSceneFlags(scene, _SCENE_FLAG_DYNAMIC)
        lib.rtcSetSceneBuildQuality(scene, _BUILD_QUALITY_LOW)
        geom = lib.rtcNewGeometry(dev, _GEOMETRY_TYPE_TRIANGLE)
        lib.rtcSetGeometryBuildQuality(geom, _BUILD_QUALITY_LOW)
        lib.rtcSetSharedGeometryBuffer(geom, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3,
                                       self._vertices.ctypes.data, 0, 12, len(self._vertices) - 1)
        lib.rtcSetSharedGeometryBuffer(geom, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3,
                                       self._faces.ctypes.data, 0, 12, len(self._faces))
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometry(scene, geom)
        lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(scene)
        self._scene = scene
        err = lib.rtcGetDeviceError(dev)
        if err:
            raise SimulationError(f'Embree failed to build the scene (error code {err})')

    def close(self) -> None:
        """Release the Embree scene (also done when the object is collected)."""
        if self._scene is not None:
            self._api.lib.rtcReleaseScene(self._scene)
            self._scene = None
        self._embreex = None

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # interpreter shutdown: the library may be gone already
            pass

    def cast(self, origins: np.ndarray, directions: np.ndarray,
             t_max: float = np.inf) -> Hits:
        """First hit of each ray ``origin + t * direction``, ``0 <= t <= t_max``.

        Args:
            origins: (N, 3) or (3,) ray origins.
            directions: (N, 3) unit directions.
            t_max: rays end here (the sensor's maximum range).

        Returns:
            :class:`Hits`, one entry per ray.
        """
        d = np.asarray(directions, dtype=np.float32).reshape(-1, 3)
        n = len(d)
        o = np.broadcast_to(np.asarray(origins, dtype=np.float32), (n, 3))
        if n == 0 or not len(self._faces):
            return Hits(np.full(n, np.inf), np.full(n, -1, np.int64),
                        np.full(n, NO_RETURN, np.uint8))
        if self._scene is not None:
            t, prim = self._cast_packets(o, d, t_max)
        else:
            res = self._embreex.run(np.ascontiguousarray(o), np.ascontiguousarray(d),
                                    dists=float(min(t_max, 3.0e38)), output=1)
            prim = res['primID'].astype(np.int64)
            prim[res['geomID'] < 0] = -1
            t = res['tfar'].astype(np.float64)
        hit = prim >= 0
        t = np.where(hit, t, np.inf)
        label = np.full(n, NO_RETURN, dtype=np.uint8)
        label[hit] = self._labels[prim[hit]]
        return Hits(t, np.where(hit, prim, -1), label)

    def _cast_packets(self, o: np.ndarray, d: np.ndarray,
                      t_max: float) -> tuple[np.ndarray, np.ndarray]:
        n = len(d)
        packets = -(-n // _LANES)
        buf = _aligned(packets * _FIELDS * _LANES * 4)
        f32 = buf.view(np.float32).reshape(packets, _FIELDS, _LANES)
        u32 = buf.view(np.uint32).reshape(packets, _FIELDS, _LANES)
        lanes = packets * _LANES
        # (N, 3) -> (packets, 3, 16): x, y, z of 16 rays next to each other.
        org = np.zeros((lanes, 3), np.float32)
        org[:n] = o
        dirs = np.zeros((lanes, 3), np.float32)
        dirs[:n] = d
        dirs[n:, 2] = -1.0
        f32[:, _F_ORG:_F_ORG + 3] = org.reshape(packets, _LANES, 3).transpose(0, 2, 1)
        f32[:, _F_DIR:_F_DIR + 3] = dirs.reshape(packets, _LANES, 3).transpose(0, 2, 1)
        f32[:, _F_TFAR] = np.float32(min(t_max, 3.0e38))
        u32[:, _F_MASK] = _INVALID_ID  # all mask bits set
        u32[:, _F_PRIM:_F_INST + 1] = _INVALID_ID
        valid = _aligned(packets * _LANES * 4).view(np.int32)
        valid[:n] = -1
        fn = self._api.lib.rtcIntersect16
        scene = self._scene
        base, vbase = buf.ctypes.data, valid.ctypes.data
        step, vstep = _FIELDS * _LANES * 4, _LANES * 4
        for p in range(packets):
            fn(vbase + p * vstep, scene, base + p * step, None)
        prim = u32[:, _F_PRIM].reshape(-1)[:n].astype(np.int64)
        geom = u32[:, _F_GEOM].reshape(-1)[:n]
        prim[geom == _INVALID_ID] = -1
        t = f32[:, _F_TFAR].reshape(-1)[:n].astype(np.float64)
        return t, prim
