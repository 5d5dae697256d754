"""Offscreen rasterisation of the virtual object and its shadow plane (paper 003 §7.2;
docs/design/overview.md, stage 10): :class:`Renderer` and its numba backend.

:class:`Renderer` rasterises, with a virtual camera matching the colour camera's intrinsics
(undistorted pinhole; OpenCV pixel centres, :mod:`rgbd_envmap.render.camera`), the PRT-shaded object
(per-vertex linear colours) and the shadow plane (per-vertex alpha), both Gouraud-interpolated
(perspective-correct), with a depth test so the object hides the plane behind it. No lighting is
applied: the colours are already the shaded radiance. It returns a :class:`Layer`, which
:func:`rgbd_envmap.render.composite.composite` draws over the colour frame.

Two backends produce the same :class:`Layer` (tests compare them pixel for pixel):

* ``"numba"`` (the default; faster than pyrender on llvmpipe, docs/design/render.md): a
  single-threaded z-buffer triangle rasteriser (:mod:`rgbd_envmap._kernels.raster`): near-plane and
  guard-band clipping in camera space, vertices snapped to 1/256 pixel and integer edge functions
  with a top-left-style tie rule (watertight: a pixel centre on an edge shared by two triangles is
  drawn exactly once), perspective-correct interpolation. A pixel is covered when its centre lies
  inside the projected triangle. The same, written out in plain numpy:
  :mod:`rgbd_envmap.reference.render_raster`.
* ``"pyrender"`` (the reference): OpenGL through EGL, :mod:`rgbd_envmap.render.gl`.

References:
    Monroy, Hudon, Smolic (2018), Dynamic Environment Mapping for Augmented Reality Applications on
    Mobile Devices, §7.2 (a virtual camera matching the colour camera).
    Gouraud, H. (1971), Continuous shading of curved surfaces, IEEE Trans. Computers C-20(6).
    Pineda, J. (1988), A parallel algorithm for polygon rasterization, SIGGRAPH '88 (edge functions).
    Sutherland, I. E., Hodgman, G. W. (1974), Reentrant polygon clipping, CACM 17(1).
    Heckbert, P., Moreton, H. (1991), Interpolation for polygon texture mapping and shading
    (perspective-correct interpolation of attribute / z and 1 / z).
"""

from __future__ import annotations

import numpy as np

from rgbd_envmap._kernels import raster as kernels
from rgbd_envmap.checks import check_method
from rgbd_envmap.errors import DTypeError, NonFiniteError, RangeError
from rgbd_envmap.render.camera import check_inputs, project_meshes
from rgbd_envmap.render.gl import PyrenderBackend
from rgbd_envmap.render.layer import Layer, RendererUnavailableError
from rgbd_envmap.types import Intrinsics, RigidTransform

__all__ = ["BACKENDS", "Layer", "Renderer", "RendererUnavailableError"]

#: Rasteriser backends accepted by :class:`Renderer`; ``"pyrender"`` is the reference, ``"numba"`` the
#: default (faster on a CPU; the tests hold the two to the same result).
BACKENDS: tuple[str, ...] = ("pyrender", "numba")


class _NumbaBackend:
    """The numba backend for one camera: ``draw`` rasterises checked inputs into a :class:`Layer`,
    reusing one z-buffer (1/z, 0 = empty) of the camera's size."""

    name = "numba"

    def __init__(self, intr: Intrinsics, near: float, far: float, crop: bool) -> None:
        self._intr = intr
        self._near = near
        self._far = far
        self._crop = crop
        self._invz = np.zeros((intr.height, intr.width), np.float64)

    def draw(self, pose, ov, of, oc, pv, pf, pa) -> Layer:
        intr = self._intr
        (obj, plane), bbox = project_meshes(pose, ((ov, of), (pv, pf)), intr, self._near)
        if bbox is None:
            return Layer.empty(intr.height, intr.width)
        if not self._crop:
            bbox = (0, intr.height, 0, intr.width)
        r0, r1, c0, c1 = bbox
        colour = np.zeros((intr.height, intr.width, 3), np.float32)
        mask = np.zeros((intr.height, intr.width), bool)
        alpha = np.zeros((intr.height, intr.width), np.float32)
        invz = self._invz
        invz[r0:r1, c0:c1] = 0.0
        args = (self._near, self._far, intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height,
                r0, r1, c0, c1, invz, colour, mask, alpha)
        for mesh, attr, is_plane in ((obj, oc, False), (plane, pa.reshape(-1, 1), True)):
            if mesh.any_front:
                kernels.raster_mesh(mesh.pc, mesh.faces, attr, mesh.xy, mesh.iz, is_plane, *args)
        return Layer(colour, mask, alpha, bbox)

    def close(self) -> None:
        self._invz = None


class Renderer:
    """A reusable offscreen renderer for a virtual camera matching a colour camera.

    Args:
        intrinsics: the colour camera (``fx, fy, cx, cy, width, height``); its distortion is ignored:
            the virtual camera is the undistorted pinhole with OpenCV pixel centres.
        near_m, far_m: clip distances along the optical axis (z-depth), metres; 0 < near < far.
        backend: ``"numba"`` (the default: the CPU rasteriser of this module, faster than pyrender
            on llvmpipe, see docs/design/render.md) or ``"pyrender"`` (the reference: OpenGL through
            EGL, :mod:`rgbd_envmap.render.gl`); :data:`BACKENDS`. Both give the same layer up to edge
            pixels and float rounding; the numba one equals
            :func:`rgbd_envmap.reference.render_raster.rasterise` bit for bit.
        crop: clear, rasterise and read back only the rectangle bounding the projected geometry (the
            default); False processes the whole frame (the same result, slower; for benchmarks).

    Raises:
        RendererUnavailableError: the backend cannot run here (no EGL / OpenGL for ``"pyrender"``).
        UnknownMethodError / RangeError / DTypeError: bad arguments.

    Use as a context manager or call :meth:`close` (frees the GL context). Example::

        with Renderer(intrinsics, backend="numba") as r:
            layer = r.render(T_world_from_cam, verts, faces, colours, plane_verts, plane_faces, alpha)
            out = composite(frame_srgb8, layer, ccm_inverse=invert_ccm(M))
    """

    def __init__(self, intrinsics: Intrinsics, *, near_m: float = 0.05, far_m: float = 20.0,
                 backend: str = "numba", crop: bool = True) -> None:
        if not isinstance(intrinsics, Intrinsics):
            raise DTypeError(f"intrinsics: expected an Intrinsics, got {type(intrinsics).__name__}")
        check_method(backend, BACKENDS, "backend")
        near, far = float(near_m), float(far_m)
        if not (np.isfinite(near) and np.isfinite(far)):
            raise NonFiniteError(f"near_m, far_m: expected finite values, got {near_m}, {far_m}")
        if not 0.0 < near < far:
            raise RangeError(f"near_m, far_m: expected 0 < near_m < far_m, got near_m={near_m}, far_m={far_m}")
        self.intrinsics = intrinsics
        self.near_m = near
        self.far_m = far
        self.backend = backend
        cls = PyrenderBackend if backend == "pyrender" else _NumbaBackend
        self.crop = bool(crop)
        self._impl = cls(intrinsics, near, far, self.crop)

    def render(self, T_world_from_cam: RigidTransform | np.ndarray, object_vertices_world: np.ndarray,
               object_faces: np.ndarray, object_colours: np.ndarray, plane_vertices_world: np.ndarray,
               plane_faces: np.ndarray, plane_alpha: np.ndarray) -> Layer:
        """Rasterise the object and the shadow plane seen from ``T_world_from_cam``.

        Args:
            T_world_from_cam: the colour camera's pose (OpenCV axes), a :class:`RigidTransform` or a
                (4, 4) float array.
            object_vertices_world: (V, 3) float, metres, world frame.
            object_faces: (F, 3) int vertex indices (either winding; no back-face culling).
            object_colours: (V, 3) float linear RGB in the reference colour space (the PRT-shaded
                radiance; values above 1 are kept, negative ones clamped to 0).
            plane_vertices_world: (P, 3) float, metres.
            plane_faces: (G, 3) int.
            plane_alpha: (P,) float in [0, 1], the shadow's opacity per plane vertex (values within 1e-6
                outside are clipped; further out raise RangeError).

        Returns:
            A :class:`Layer` of the camera's size. An object and plane behind the camera or out of
            view give an empty layer (no error). Empty meshes (0 faces) are allowed.

        Raises:
            ShapeError / DTypeError / NonFiniteError / RangeError: bad inputs (message names the
            argument); RendererUnavailableError: the renderer is closed.
        """
        if self._impl is None:
            raise RendererUnavailableError("Renderer.render: the renderer is closed")
        inputs = check_inputs(T_world_from_cam, object_vertices_world, object_faces, object_colours,
                               plane_vertices_world, plane_faces, plane_alpha)
        return self._impl.draw(*inputs)

    def close(self) -> None:
        """Free the backend's resources (the GL context for pyrender). Idempotent."""
        if self._impl is not None:
            impl, self._impl = self._impl, None
            impl.close()

    @property
    def closed(self) -> bool:
        return self._impl is None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown: GL may already be gone
            pass
