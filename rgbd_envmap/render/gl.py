"""The pyrender backend of :class:`~rgbd_envmap.render.raster.Renderer`: OpenGL through EGL (the
reference for the numba rasteriser).

pyrender 0.1.45 on an EGL (or OSMesa) context, with a subclass of its ``Renderer`` that draws into a
single-sample float32 framebuffer (pyrender's own is 4× MSAA RGBA8, which would quantise linear
colours to 8 bits and blend mask edges), clears, draws and reads back only the scissor rectangle
that bounds the projected geometry, and skips the depth readback. The scene (two meshes and a
camera) is built once; per frame only the camera pose and the vertex buffers (positions, colours,
alphas) are updated (``glBufferSubData``). OpenGL puts pixel centres at half-integers (window
coordinates), so the pyrender camera gets principal point (cx + ½, cy + ½) to match the OpenCV
convention of :mod:`rgbd_envmap.render.camera`.

Platform: PyOpenGL picks its platform when first imported, and pyrender needs a headless one (EGL
works with Mesa's llvmpipe). The first backend created sets ``PYOPENGL_PLATFORM=egl`` unless the
caller has set it; importing this module sets nothing and imports no OpenGL.
"""

from __future__ import annotations

import os
from functools import lru_cache

import numpy as np

from rgbd_envmap._kernels import raster_gl as kernels
from rgbd_envmap.geometry import opengl_from_opencv
from rgbd_envmap.render.camera import project_meshes
from rgbd_envmap.render.layer import Layer, RendererUnavailableError
from rgbd_envmap.types import Intrinsics

__all__ = ["PyrenderBackend", "egl_available"]


def _choose_platform() -> None:
    """``PYOPENGL_PLATFORM=egl`` unless set: before the first import of OpenGL (pyrender imports it)."""
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")


def _make_platform(width: int, height: int):
    """An offscreen GL platform for pyrender (EGL or OSMesa, per ``PYOPENGL_PLATFORM``)."""
    name = os.environ.get("PYOPENGL_PLATFORM", "")
    if name == "egl":
        from pyrender.platforms import egl

        device = egl.get_device_by_index(int(os.environ.get("EGL_DEVICE_ID", "0")))
        platform = egl.EGLPlatform(width, height, device=device)
    elif name == "osmesa":
        from pyrender.platforms.osmesa import OSMesaPlatform

        platform = OSMesaPlatform(width, height)
    else:
        raise RendererUnavailableError(
            f"PYOPENGL_PLATFORM: expected 'egl' or 'osmesa' for offscreen rendering, got {name!r}")
    platform.init_context()
    platform.make_current()
    return platform


@lru_cache(maxsize=1)
def _layer_renderer_class():
    """pyrender.Renderer subclass drawing into a single-sample RGBA32F framebuffer inside a scissor
    rectangle, uploading pending vertex data before drawing, and reading back only that rectangle's
    colour (no depth readback). Built lazily so importing this module does not import OpenGL."""
    import pyrender
    from OpenGL import GL

    class _LayerGLRenderer(pyrender.Renderer):
        def __init__(self, width: int, height: int) -> None:
            super().__init__(width, height)
            self.scissor = (0, 0, width, height)  # x, y (GL: from the bottom), w, h
            self.pending: list[tuple[object, np.ndarray]] = []

        def _update_context(self, scene, flags):
            super()._update_context(scene, flags)
            for primitive, data in self.pending:
                GL.glBindBuffer(GL.GL_ARRAY_BUFFER, primitive._buffers[0])
                GL.glBufferSubData(GL.GL_ARRAY_BUFFER, 0, data.nbytes, data)
            GL.glBindBuffer(GL.GL_ARRAY_BUFFER, 0)
            self.pending = []

        def _configure_main_framebuffer(self):
            if self._main_fb is not None:
                return
            w, h = self.viewport_width, self.viewport_height
            self._main_cb, self._main_db = GL.glGenRenderbuffers(2)
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_cb)
            GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA32F, w, h)
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_db)
            GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_DEPTH_COMPONENT24, w, h)
            self._main_fb = GL.glGenFramebuffers(1)
            GL.glBindFramebuffer(GL.GL_DRAW_FRAMEBUFFER, self._main_fb)
            GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER,
                                         self._main_cb)
            GL.glFramebufferRenderbuffer(GL.GL_DRAW_FRAMEBUFFER, GL.GL_DEPTH_ATTACHMENT, GL.GL_RENDERBUFFER,
                                         self._main_db)
            status = GL.glCheckFramebufferStatus(GL.GL_DRAW_FRAMEBUFFER)
            if status != GL.GL_FRAMEBUFFER_COMPLETE:
                raise RendererUnavailableError(f"float32 framebuffer is incomplete (status {status:#x})")
            # pyrender's forward pass draws into _main_fb_ms: the same single-sample buffer here.
            self._main_fb_ms = self._main_fb
            self._main_fb_dims = (w, h)

        def _delete_main_framebuffer(self):
            if self._main_fb is not None:
                GL.glDeleteFramebuffers(1, [self._main_fb])
                GL.glDeleteRenderbuffers(2, [self._main_cb, self._main_db])
            self._main_fb = self._main_cb = self._main_db = None
            self._main_fb_ms = self._main_cb_ms = self._main_db_ms = None
            self._main_fb_dims = (None, None)

        def _configure_forward_pass_viewport(self, flags):
            super()._configure_forward_pass_viewport(flags)
            GL.glEnable(GL.GL_SCISSOR_TEST)  # also limits the glClear in the forward pass
            GL.glScissor(*self.scissor)

        def _read_main_framebuffer(self, scene, flags):
            x, y, w, h = self.scissor
            out = np.empty((h, w, 4), np.float32)
            GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._main_fb)
            GL.glReadPixels(x, y, w, h, GL.GL_RGBA, GL.GL_FLOAT, out)
            return out  # rows bottom-up, as GL stores them

    return _LayerGLRenderer


class _GLMesh:
    """One pyrender mesh node whose vertex buffer (position xyz, colour rgba: 7 float32) is rewritten
    each frame; rebuilt only when the faces or the vertex count change."""

    def __init__(self) -> None:
        self.node = None
        self.primitive = None
        self.faces: np.ndarray | None = None
        self.data: np.ndarray | None = None

    def update(self, scene, renderer, vertices: np.ndarray, faces: np.ndarray, rgba_fill) -> None:
        import pyrender

        n = len(vertices)
        if self.node is not None and (self.faces is None or self.faces.shape != faces.shape
                                      or len(self.data) != n or not np.array_equal(self.faces, faces)):
            scene.remove_node(self.node)
            self.node = None
        if self.data is None or len(self.data) != n:
            self.data = np.empty((n, 7), np.float32)
        self.data[:, :3] = vertices
        rgba_fill(self.data[:, 3:])
        if len(faces) == 0:
            self.faces = faces.copy()
            return
        if self.node is None:
            material = pyrender.MetallicRoughnessMaterial(baseColorFactor=(1.0, 1.0, 1.0, 1.0), doubleSided=True)
            self.primitive = pyrender.Primitive(positions=self.data[:, :3], indices=faces, color_0=self.data[:, 3:],
                                                material=material)
            self.node = scene.add(pyrender.Mesh([self.primitive]))
            self.faces = faces.copy()
        else:
            renderer.pending.append((self.primitive, self.data))


class PyrenderBackend:
    """The pyrender backend for one camera: ``draw`` rasterises checked inputs
    (:func:`rgbd_envmap.render.camera.check_inputs`) into a :class:`Layer`; ``close`` frees the GL
    context. Raises :class:`RendererUnavailableError` when no offscreen context can be made."""

    name = "pyrender"

    def __init__(self, intr: Intrinsics, near: float, far: float, crop: bool) -> None:
        _choose_platform()
        try:
            import pyrender

            self._platform = _make_platform(intr.width, intr.height)
            self._renderer = _layer_renderer_class()(intr.width, intr.height)
        except RendererUnavailableError:
            raise
        except Exception as exc:  # any GL / EGL failure means "not available here"
            raise RendererUnavailableError(
                f"backend 'pyrender': cannot create an offscreen OpenGL context "
                f"(PYOPENGL_PLATFORM={os.environ.get('PYOPENGL_PLATFORM')!r}): {type(exc).__name__}: {exc}") from exc
        self._pyrender = pyrender
        self._flags = (pyrender.RenderFlags.FLAT | pyrender.RenderFlags.RGBA | pyrender.RenderFlags.SKIP_CULL_FACES
                       | pyrender.RenderFlags.OFFSCREEN)
        self._intr = intr
        self._near = near
        self._crop = crop
        self._scene = pyrender.Scene(bg_color=(0.0, 0.0, 0.0, 0.0), ambient_light=(0.0, 0.0, 0.0))
        # OpenGL pixel centres sit at half-integers: shift the principal point by half a pixel.
        camera = pyrender.IntrinsicsCamera(intr.fx, intr.fy, intr.cx + 0.5, intr.cy + 0.5, znear=near, zfar=far)
        self._camera_node = self._scene.add(camera, pose=np.eye(4))
        self._object = _GLMesh()
        self._plane = _GLMesh()

    def draw(self, pose, ov, of, oc, pv, pf, pa) -> Layer:
        intr = self._intr
        _, bbox = project_meshes(pose, ((ov, of), (pv, pf)), intr, self._near)
        if bbox is None:
            return Layer.empty(intr.height, intr.width)
        if not self._crop:
            bbox = (0, intr.height, 0, intr.width)
        r0, r1, c0, c1 = bbox
        # The flat shader clamps colours to [0, 1]: scale HDR colours down for the draw and back up after.
        scale = max(float(oc.max(initial=0.0)), 1.0)

        def object_rgba(dst):
            np.multiply(oc, 1.0 / scale, out=dst[:, :3])
            dst[:, 3] = kernels.GL_OBJECT_ALPHA

        def plane_rgba(dst):
            dst[:, 0] = pa
            dst[:, 1:3] = 0.0
            dst[:, 3] = kernels.GL_PLANE_ALPHA

        self._platform.make_current()
        self._object.update(self._scene, self._renderer, ov, of, object_rgba)
        self._plane.update(self._scene, self._renderer, pv, pf, plane_rgba)
        self._scene.set_pose(self._camera_node, opengl_from_opencv(pose).matrix)
        self._renderer.scissor = (c0, intr.height - r1, c1 - c0, r1 - r0)
        rgba = self._renderer.render(self._scene, self._flags)
        return _layer_from_rgba(rgba, scale, bbox, intr)

    def close(self) -> None:
        if self._renderer is None:
            return
        try:
            self._platform.make_current()
            self._renderer.delete()
        finally:
            self._renderer = None
            _destroy_platform(self._platform)
            self._platform = None


def _destroy_platform(platform) -> None:
    """Destroy the context only: pyrender's EGL ``delete_context`` also calls ``eglTerminate`` on the
    display, which is shared by every EGL context of the process and would kill other renderers."""
    display = getattr(platform, "_egl_display", None)
    context = getattr(platform, "_egl_context", None)
    if display is not None and context is not None:
        from OpenGL import EGL

        EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
        EGL.eglDestroyContext(display, context)
    if display is not None:
        # Platform.__del__ calls delete_context(), which would still terminate the shared display.
        platform._egl_context = None
        platform._egl_display = None
    else:
        platform.delete_context()


def _layer_from_rgba(rgba: np.ndarray, scale: float, bbox, intr: Intrinsics) -> Layer:
    """The layer of a GL read-back of the bbox (see :func:`rgbd_envmap._kernels.raster_gl.split_rgba`)."""
    colour = np.zeros((intr.height, intr.width, 3), np.float32)
    mask = np.zeros((intr.height, intr.width), bool)
    alpha = np.zeros((intr.height, intr.width), np.float32)
    kernels.split_rgba(rgba, np.float32(scale), bbox[0], bbox[2], colour, mask, alpha)
    return Layer(colour, mask, alpha, bbox)


def egl_available() -> tuple[bool, str]:
    """Whether the pyrender backend can create an offscreen context here: ``(ok, reason)``.
    Creates and destroys a 1×1 context."""
    try:
        r = PyrenderBackend(Intrinsics(1, 1, 1.0, 1.0, 0.0, 0.0), 0.05, 20.0, True)
    except RendererUnavailableError as exc:
        return False, str(exc)
    except ImportError as exc:
        return False, f"pyrender / PyOpenGL not importable: {exc}"
    r.close()
    return True, ""
