"""The far field's depth-corrected lookup evaluated per pixel, in the fragment shader of a cell's quad.

Why: on the CPU (:func:`citylod.lod.kernels.slf.depth_corrected_colours`) a cell whose view direction moved
costs a ray march and a blend of four directions at each of its texels, then a new texture, every frame of a
moving view (about 0.45 ms a 64² cell here; docs/PERFORMANCE_LOG.md). Ruiters evaluates the light field on the
GPU. Here the stored directions' images and ray marches go to the GPU once per cell and direction patch, as
textures, and a frame only sets each cell's uniforms. The shader then runs the same march and blend
per fragment, at the fragment's own texture position rather than at texel centres that are then filtered.
On a GPU that is free. On Mesa's llvmpipe the fragment shader runs in SIMD over the rasteriser's threads:
whole-city overview 17–18 ms against 21 ms for the CPU evaluation, texture writes and draw; far flight 8–9
against 11 ms (8,000 houses, docs/BENCHMARKS.md).

The shader is :func:`~citylod.lod.kernels.slf._ray_top` and
:func:`~citylod.lod.kernels.slf._blend_texel` in GLSL. It first runs the exact column march over the building
tops (``slfTop``, T × T heights, row 0 the north edge). Then, for each of the four blended directions, it takes
a bilinear sample of that direction's image at the parallax-shifted position (``slfImages``, the patch's
images as tiles of an atlas, clamped to the tile's texel centres so no neighbour bleeds in). A direction's
sample counts where its own march (``slfSeen``, heights in an atlas of the same layout) meets the viewed point
within ``slfTol``; where none does, the plain weights count.

A pixel wider than a texel averages the blend at four points of its footprint (a rotated grid), with the
directions that see the point decided once, at its centre. The CPU path's texture of the evaluated field is
mip-mapped for the same reason. A point-sampled minified field aliases: flicker 7.7–9.3 against 5.6–7.1 with
the four points, on the sample cities (docs/PERFORMANCE_LOG.md). A cross-fade to the ground colour
(``slfFade``) and a flat white for the field mask (``slfWhite``) are uniforms too.

Where a GL cannot build the shader, VTK draws the quad with its atlas and reports it only as an ErrorEvent of
the mapper; :class:`~citylod.render.slf.SlfView` watches for it and goes over to the CPU lookup, with a warning.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.render import _vtk

__all__ = ["AtlasLayout", "encode_heights", "height_texture", "install_lookup", "rgb_texture", "set_fade", "set_images",
           "set_lookup", "texels", "texels_changed", "texture_bytes"]

_DEC = """
//VTK::TCoord::Dec
float slfHeight(sampler2D t, ivec2 p) {  // metres from 24 bits, 1/1024 m a step (height_texture)
  vec3 b = floor(texelFetch(t, p, 0).rgb * 255.0 + 0.5);
  return (b.r * 65536.0 + b.g * 256.0 + b.b) / 1024.0;
}
float slfTopAt(int i, int j) { return slfHeight(slfTop, ivec2(j, i)); }
float slfRayTop(float r, float c) {
  int T = slfT;
  float t = float(T);
  float x0 = c + 0.5, y0 = r + 0.5;
  float dx = slfRay.x, dy = -slfRay.y;
  float s_hi = slfRay.z;
  if (s_hi <= 0.0) return 0.0;
  if (dx > 0.0) s_hi = min(s_hi, (t - x0) / dx); else if (dx < 0.0) s_hi = min(s_hi, -x0 / dx);
  if (dy > 0.0) s_hi = min(s_hi, (t - y0) / dy); else if (dy < 0.0) s_hi = min(s_hi, -y0 / dy);
  int j = clamp(int(floor(x0 + s_hi * dx)), 0, T - 1);
  int i = clamp(int(floor(y0 + s_hi * dy)), 0, T - 1);
  for (int k = 0; k < 2 * T + 4; ++k) {
    float sx = dx > 0.0 ? (float(j) - x0) / dx : (dx < 0.0 ? (float(j + 1) - x0) / dx : -1.0);
    float sy = dy > 0.0 ? (float(i) - y0) / dy : (dy < 0.0 ? (float(i + 1) - y0) / dy : -1.0);
    float s_lo = max(max(sx, sy), 0.0);
    float h = slfTopAt(i, j);
    if (s_lo < s_hi && h >= s_lo) return min(h, s_hi);
    if (s_lo <= 0.0) break;
    if (sx >= sy) j += dx > 0.0 ? -1 : 1;
    if (sy >= sx) i += dy > 0.0 ? -1 : 1;
    if (i < 0 || i >= T || j < 0 || j >= T) break;
    s_hi = s_lo;
  }
  return 0.0;
}
vec4 slfWeights(float r, float c, float hh) {  // _blend_texel's weights at (r, c): the directions that see hh
  vec4 seen = vec4(0.0);
  vec4 plain = vec4(0.0);
  for (int k = 0; k < 4; ++k) {
    float wk = slfW[k];
    if (wk <= 0.0) continue;
    plain[k] = wk;
    vec2 org = vec2(mod(slfTile[k], float(slfCols)), floor(slfTile[k] / float(slfCols))) * float(slfT);
    vec2 p = vec2(c + hh * slfShiftX[k], r - hh * slfShiftY[k]);
    ivec2 ri = clamp(ivec2(floor(p + 0.5)), ivec2(0), ivec2(slfT - 1));
    if (abs(slfHeight(slfSeen, ivec2(org) + ri) - hh) <= slfTol) seen[k] = wk;
  }
  float s = seen.x + seen.y + seen.z + seen.w;
  return s > 1e-9 ? seen / s : plain / max(plain.x + plain.y + plain.z + plain.w, 1e-9);
}
vec3 slfBlend(float r, float c, float hh, vec4 ew) {  // the images at (r, c) blended with weights ew (0..255)
  float T = float(slfT);
  vec2 atlas = vec2(textureSize(slfImages, 0));
  vec3 acc = vec3(0.0);
  for (int k = 0; k < 4; ++k) {
    if (ew[k] <= 0.0) continue;
    vec2 org = vec2(mod(slfTile[k], float(slfCols)), floor(slfTile[k] / float(slfCols))) * T;
    vec2 q = clamp(vec2(c + hh * slfShiftX[k], r - hh * slfShiftY[k]), vec2(0.0), vec2(T - 1.0));
    acc += ew[k] * textureLod(slfImages, (org + q + 0.5) / atlas, 0.0).rgb * 255.0;
  }
  return acc;
}
"""

_IMPL = """
  {
  float T = float(slfT);
  float c = tcoordVCVSOutput.x * T - 0.5;
  float r = (1.0 - tcoordVCVSOutput.y) * T - 0.5;
  float hh = slfRayTop(r, c);
  // A pixel wider than a texel averages the blend at four points of its footprint (a rotated grid): the
  // lookup of a minified field is otherwise a point sample of it, and aliases.
  vec2 gx = dFdx(vec2(c, r));
  vec2 gy = dFdy(vec2(c, r));
  // Which directions see the point is decided once, at the pixel's centre.
  vec4 ew = slfWeights(r, c, hh);
  vec3 col;
  if (slfAntialias > 0.5 && max(length(gx), length(gy)) > 1.0) {
    col = 0.25 * (slfBlend(r + 0.375 * gx.y + 0.125 * gy.y, c + 0.375 * gx.x + 0.125 * gy.x, hh, ew)
                  + slfBlend(r - 0.375 * gx.y - 0.125 * gy.y, c - 0.375 * gx.x - 0.125 * gy.x, hh, ew)
                  + slfBlend(r + 0.125 * gx.y - 0.375 * gy.y, c + 0.125 * gx.x - 0.375 * gy.x, hh, ew)
                  + slfBlend(r - 0.125 * gx.y + 0.375 * gy.y, c - 0.125 * gx.x + 0.375 * gy.x, hh, ew));
  } else {
    col = slfBlend(r, c, hh, ew);
  }
  col = mix(col / 255.0, slfGround, slfFade);
  gl_FragData[0] = slfWhite > 0.5 ? vec4(1.0) : vec4(col, 1.0);
  }
"""


class AtlasLayout:
    """Where each of a patch's ``p`` stored directions lies in the atlas: tile ``k`` at column ``k % cols``,
    row ``k // cols``, each ``t`` × ``t`` texels."""

    def __init__(self, p: int, t: int) -> None:
        self.p, self.t = int(p), int(t)
        self.cols = int(math.ceil(math.sqrt(self.p)))
        self.rows = int(math.ceil(self.p / self.cols))

    def tile(self, k: int) -> tuple[slice, slice]:
        y, x = divmod(int(k), self.cols)
        return slice(y * self.t, (y + 1) * self.t), slice(x * self.t, (x + 1) * self.t)

    @property
    def shape(self) -> tuple[int, int]:
        return self.rows * self.t, self.cols * self.t


def _texture(arr: npt.NDArray[Any], interpolate: bool) -> Any:
    """A texture holding ``arr`` with its row 0 as the texture's row 0 (texelFetch addresses rows as stored)."""
    h, w = arr.shape[:2]
    nc = 1 if arr.ndim == 2 else arr.shape[2]
    img = _vtk.vtkImageData()
    img.SetDimensions(w, h, 1)
    img.GetPointData().SetScalars(_vtk.numpy_to_vtk(np.ascontiguousarray(arr).reshape(-1, nc), deep=True))
    tex = _vtk.vtkTexture()
    tex.SetInputData(img)
    tex.SetColorModeToDirectScalars()  # the bytes as they are, never through a colour table
    tex.SetInterpolate(interpolate)
    tex.MipmapOff()
    tex.EdgeClampOn()
    return tex


def rgb_texture(arr: npt.NDArray[np.uint8]) -> Any:
    """An RGB8 texture, filtered bilinearly (the images' atlas)."""
    return _texture(arr, True)


def encode_heights(arr: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """Heights (m, ≥ 0) as three bytes a texel, 1/1024 m a step up to 16 km: VTK uploads a float image as
    normalised 8-bit colours, so heights travel as bytes and the shader (``slfHeight``) decodes them."""
    q = np.clip(np.rint(np.asarray(arr, np.float64) * 1024.0), 0, 2**24 - 1).astype(np.uint32)
    return np.stack([(q >> 16) & 255, (q >> 8) & 255, q & 255], axis=-1).astype(np.uint8)


def height_texture(arr: npt.ArrayLike) -> Any:
    """Heights for texelFetch (:func:`encode_heights`), not filtered."""
    return _texture(encode_heights(arr), False)


def texels(tex: Any) -> npt.NDArray[np.uint8]:
    """The texture's image as a writable array (rows, columns, channels), VTK's own memory: write into it,
    then :func:`texels_changed`."""
    img = tex.GetInput()
    w, h, _ = img.GetDimensions()
    scalars = img.GetPointData().GetScalars()
    return _vtk.vtk_to_numpy(scalars).reshape(h, w, scalars.GetNumberOfComponents())


def texels_changed(tex: Any) -> None:
    """VTK uploads the texture's image again at the next render."""
    img = tex.GetInput()
    img.GetPointData().GetScalars().Modified()
    img.Modified()
    tex.Modified()


def texture_bytes(tex: Any) -> int:
    """Bytes of the texture's image (VTK's copy; the GL texture holds as many again)."""
    scalars = tex.GetInput().GetPointData().GetScalars()
    return int(scalars.GetNumberOfValues()) * int(scalars.GetDataTypeSize())


def install_lookup(actor: Any, top: Any, images: Any, seen: Any, t: int, cols: int, ground_rgb: Any,
                   antialias: bool = True) -> None:
    """Make ``actor`` (a cell's textured quad) draw its field through the lookup shader, with ``top``,
    ``images`` and ``seen`` textures and a patch atlas of ``cols`` tiles a row of ``t`` texels; ``antialias``:
    average four points of a pixel wider than a texel (False: one, faster, aliased)."""
    actor.SetTexture(None)
    prop = actor.GetProperty()
    prop.SetTexture("slfTop", top)
    prop.SetTexture("slfImages", images)
    prop.SetTexture("slfSeen", seen)
    sp = actor.GetShaderProperty()
    sp.ClearAllFragmentShaderReplacements()
    sp.AddFragmentShaderReplacement("//VTK::TCoord::Dec", True, _DEC, False)
    sp.AddFragmentShaderReplacement("//VTK::TCoord::Impl", True, _IMPL, False)
    u = sp.GetFragmentCustomUniforms()
    u.SetUniformi("slfT", int(t))
    u.SetUniformi("slfCols", int(cols))
    u.SetUniformf("slfTol", 1.0)
    u.SetUniformf("slfFade", 0.0)
    u.SetUniformf("slfAntialias", 1.0 if antialias else 0.0)
    u.SetUniformf("slfWhite", 0.0)
    u.SetUniform3f("slfGround", [float(x) / 255.0 for x in ground_rgb])
    for name in ("slfW", "slfTile", "slfShiftX", "slfShiftY"):
        u.SetUniform4f(name, [0.0, 0.0, 0.0, 0.0])
    u.SetUniform3f("slfRay", [0.0, 0.0, 0.0])


def set_images(actor: Any, images: Any, seen: Any, cols: int) -> None:
    """Point the lookup at another patch's atlases."""
    prop = actor.GetProperty()
    prop.SetTexture("slfImages", images)
    prop.SetTexture("slfSeen", seen)
    actor.GetShaderProperty().GetFragmentCustomUniforms().SetUniformi("slfCols", int(cols))


def _vec4(x: list[float]) -> list[float]:
    return [float(v) for v in x[:4]] + [0.0] * (4 - min(len(x), 4))


def set_lookup(actor: Any, loc: Any, w: Any, shifts: Any, ray: tuple[float, float, float]) -> None:
    """The view's uniforms: the blended directions' tiles ``loc`` and weights ``w``, their parallax per metre
    of height ``shifts`` (n, 2) in texels (x, y), and the view's march (texels per metre of height in x and
    y, and the highest top). Plain lists: this runs for every cell whose direction moved, every frame."""
    u = actor.GetShaderProperty().GetFragmentCustomUniforms()
    u.SetUniform4f("slfTile", _vec4(np.asarray(loc).tolist()))
    u.SetUniform4f("slfW", _vec4(np.asarray(w).tolist()))
    sh = np.asarray(shifts, np.float64).reshape(-1, 2).T.tolist()
    u.SetUniform4f("slfShiftX", _vec4(sh[0]))
    u.SetUniform4f("slfShiftY", _vec4(sh[1]))
    u.SetUniform3f("slfRay", [float(ray[0]), float(ray[1]), float(ray[2])])


def set_fade(actor: Any, fade: float, white: bool = False) -> None:
    """Blend the cell's field towards the ground colour by ``fade`` (0: the field); ``white``: draw it flat
    white (the field mask of a measurement)."""
    u = actor.GetShaderProperty().GetFragmentCustomUniforms()
    u.SetUniformf("slfFade", float(fade))
    u.SetUniformf("slfWhite", 1.0 if white else 0.0)
