"""Preview images of a simulated session: a contact sheet of colour frames, depth and confidence
images of ToF packets, and the ground-truth environment map."""

from __future__ import annotations

import cv2
import numpy as np

from rgbd_envmap.colour import decode_nv21, linear_to_srgb
from rgbd_envmap.geometry import project_points
from rgbd_envmap.types import ColourPacket, DepthPacket, Intrinsics

__all__ = ["tonemap", "contact_sheet", "colour_thumbnail", "depth_confidence_images", "depth_to_colourmap"]


def tonemap(radiance: np.ndarray, valid: np.ndarray | None = None, key: float = 0.18) -> np.ndarray:
    """Linear radiance (H, W, 3) → uint8 sRGB, exposed so the median luminance maps to ``key``."""
    luma = radiance @ np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)
    sel = luma[valid] if valid is not None else luma.ravel()
    median = float(np.median(sel)) if sel.size else 1.0
    scale = key / max(median, 1e-6)
    out = linear_to_srgb(np.clip(radiance * scale, 0.0, 1.0))
    if valid is not None:
        out = np.where(valid[..., None], out, 0.0)
    return np.round(out * 255).astype(np.uint8)


def colour_thumbnail(packet: ColourPacket, width: int = 320) -> np.ndarray:
    """Decoded sRGB thumbnail (h, width, 3) uint8 of a colour packet."""
    rgb = decode_nv21(packet.nv21, packet.height, packet.width)
    height = max(1, round(packet.height * width / packet.width))
    return cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)


def depth_to_colourmap(depth_m: np.ndarray, valid: np.ndarray, max_m: float = 4.0) -> np.ndarray:
    """(H, W) depth → (H, W, 3) uint8 RGB with the turbo colour map; invalid pixels black."""
    scaled = np.clip(depth_m / max_m * 255.0, 0, 255).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgb[~valid] = 0
    return rgb


def depth_confidence_images(packet: DepthPacket, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Project a point cloud into its sensor's image: (depth RGB, confidence RGB) uint8 images.

    Confidence is drawn grey (0 → black, 1 → white), with points under 0.7 (the paper's "unknown")
    tinted red."""
    h, w = intrinsics.height, intrinsics.width
    depth = np.zeros((h, w), np.float32)
    conf = np.zeros((h, w), np.float32)
    valid = np.zeros((h, w), bool)
    if len(packet.points_m):
        uv, ok = project_points(packet.points_m, intrinsics)
        col = np.round(uv[:, 0])
        row = np.round(uv[:, 1])
        ok &= (col >= 0) & (col < w) & (row >= 0) & (row < h)
        r, c = row[ok].astype(int), col[ok].astype(int)
        depth[r, c] = packet.points_m[ok, 2]
        conf[r, c] = packet.confidence[ok]
        valid[r, c] = True
    conf_rgb = np.repeat((conf * 255).astype(np.uint8)[..., None], 3, axis=2)
    low = valid & (conf < 0.7)
    conf_rgb[low] = (np.array([255, 60, 60]) * conf[low, None]).astype(np.uint8) + np.array([60, 0, 0], np.uint8)
    return depth_to_colourmap(depth, valid), conf_rgb


def contact_sheet(images: list[np.ndarray], columns: int = 4, pad: int = 4) -> np.ndarray:
    """Tile equally sized (h, w, 3) uint8 images into a grid with ``pad`` pixels of black between."""
    if not images:
        return np.zeros((1, 1, 3), np.uint8)
    h, w = images[0].shape[:2]
    rows = (len(images) + columns - 1) // columns
    sheet = np.zeros((rows * (h + pad) + pad, columns * (w + pad) + pad, 3), np.uint8)
    for i, img in enumerate(images):
        r, c = divmod(i, columns)
        sheet[pad + r * (h + pad): pad + r * (h + pad) + h, pad + c * (w + pad): pad + c * (w + pad) + w] = img
    return sheet
