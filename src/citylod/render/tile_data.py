"""Decoding a tile into arrays ready for VTK, on a loader's worker thread.

:func:`prepare_tile` is the ``load_fn`` of :class:`citylod.lod.runtime.loader.TileLoader` for rendering: it reads
and decodes the tile content (:meth:`citylod.io.tiles3d.Tile.load_content`), splits surface from skirt
triangles, puts them in an order the GPU's vertex cache reuses (:mod:`citylod.render.mesh_order`), turns glTF
texture coordinates into VTK's (origin bottom-left) and decodes the texture image
into a numpy array. The render thread then only wraps these arrays (no copy) in VTK objects. The texture
decoder is a VTK image reader fed from memory; it is a transient, unshared object that never touches
OpenGL, which VTK supports off the main thread.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from citylod.core.errors import InputError
from citylod.io import image as image_io
from citylod.io.tiles3d import PointData
from citylod.render import _vtk, flat_colors, mesh_order


@dataclass
class PreparedMesh:
    """One mesh, as arrays VTK takes without copying.

    ``positions`` (N, 3) float32 relative to the tile origin; ``surface`` and ``skirt`` the flat
    connectivity (3·M,) int64 of each triangle set; ``tcoords`` (N, 2) float32 with VTK's bottom-left
    origin; ``texture`` (H, W, C) uint8, rows bottom-up as VTK stores images; ``colors`` (N, 4) uint8.
    ``provoking``: every triangle's last corner is a vertex of its own
    (:func:`citylod.render.flat_colors.provoking_layout`), so a per-vertex colour can be its triangle's.
    ``skirt_groups``: when set, the skirt triangles are ordered by the side of the tile they hang on, and
    these six triangle offsets delimit the groups (no side, then sides 0–3: :mod:`citylod.render.skirts`).
    ``double_sided`` False: back faces are culled (the content's glTF material says so).
    """

    positions: npt.NDArray[np.float32]
    surface: npt.NDArray[np.int64]
    skirt: npt.NDArray[np.int64]
    tcoords: npt.NDArray[np.float32] | None = None
    texture: npt.NDArray[np.uint8] | None = None
    colors: npt.NDArray[np.uint8] | None = None
    name: str = "surface"
    provoking: bool = False
    skirt_groups: tuple[int, ...] | None = None
    double_sided: bool = True

    @property
    def triangles(self) -> int:
        return (len(self.surface) + len(self.skirt)) // 3

    @property
    def nbytes(self) -> int:
        n = self.positions.nbytes + self.surface.nbytes + self.skirt.nbytes
        for a in (self.tcoords, self.texture, self.colors):
            n += 0 if a is None else a.nbytes
        return n


@dataclass
class PreparedTile:
    """A decoded tile: meshes and points (:class:`~citylod.io.tiles3d.PointData`), and their sizes."""

    key: str
    level: int
    meshes: list[PreparedMesh] = field(default_factory=list)
    points: PointData | None = None

    @property
    def triangles(self) -> int:
        return sum(m.triangles for m in self.meshes)

    @property
    def point_count(self) -> int:
        return 0 if self.points is None else len(self.points.positions)

    @property
    def nbytes(self) -> int:
        return sum(m.nbytes for m in self.meshes) + (0 if self.points is None else self.points.nbytes)


def decode_image(data: bytes, source: str = "") -> npt.NDArray[np.uint8]:
    """Decode JPEG, PNG, WebP or KTX2 bytes into (H, W, C) uint8 with rows bottom-up (VTK's image order).

    JPEG and PNG go through VTK's readers straight from memory; WebP (``EXT_texture_webp``), which VTK does
    not read, through OpenImageIO; KTX2 (``KHR_texture_basisu``) through the Basis Universal transcoder
    (:func:`citylod.io.image.decode_ktx2`).

    Raises
    ------
    InputError
        If the bytes are none of these formats or the decoder fails.
    """
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        reader: Any = _vtk.vtkPNGReader()
    elif data[:3] == b"\xff\xd8\xff":
        reader = _vtk.vtkJPEGReader()
    elif (data[:4] == b"RIFF" and data[8:12] == b"WEBP") or data[:12] == image_io.KTX2_MAGIC:
        return np.ascontiguousarray(image_io.decode_image(bytes(data), source)[::-1])
    else:
        raise InputError("tile texture is neither JPEG, PNG, WebP nor KTX2", source)
    stream = _vtk.vtkMemoryResourceStream()
    stream.SetBuffer(bytes(data), len(data), True)  # copy: the stream must not outlive a Python buffer
    reader.SetStream(stream)
    reader.Update()
    image = reader.GetOutput()
    scalars = image.GetPointData().GetScalars()
    dims = image.GetDimensions()
    if scalars is None or dims[0] * dims[1] == 0:
        raise InputError("tile texture could not be decoded", source)
    arr = _vtk.vtk_to_numpy(scalars).copy()
    return arr.reshape(dims[1], dims[0], -1).astype(np.uint8, copy=False)


def _flat(faces: np.ndarray) -> npt.NDArray[np.int64]:
    return np.ascontiguousarray(faces, dtype=np.int64).reshape(-1)


def prepare_content(content: Any, key: str, level: int, source: str = "") -> PreparedTile:
    """Turn a :class:`~citylod.io.tiles3d.TileContent` into a :class:`PreparedTile` (vectorised)."""
    out = PreparedTile(key=key, level=level, points=content.points)
    for mesh in content.meshes:
        faces = np.asarray(mesh.faces).reshape(-1, 3)
        if mesh.skirt is not None and len(mesh.skirt) == len(faces):
            skirt = np.asarray(mesh.skirt, bool)
        else:
            skirt = np.zeros(len(faces), bool)
        tcoords = texture = None
        if mesh.uv is not None and mesh.texture:
            # glTF puts the uv origin at the image's top-left, VTK at its bottom-left: flip v.
            uv = np.asarray(mesh.uv, np.float32)
            tcoords = np.empty_like(uv)
            tcoords[:, 0] = uv[:, 0]
            tcoords[:, 1] = 1.0 - uv[:, 1]
            texture = decode_image(mesh.texture, source)
        positions = np.ascontiguousarray(mesh.positions, dtype=np.float32)
        colors = None if mesh.colors is None else np.ascontiguousarray(mesh.colors, np.uint8)
        surface, skirt_faces = _flat(faces[~skirt]), _flat(faces[skirt])
        provoking = texture is None and colors is None and flat_colors.enabled() and len(faces) > 0
        if provoking:
            # Untextured meshes are drawn with one baked colour per triangle: give each triangle a last
            # corner of its own to carry it (render/flat_colors.py), before ordering for the cache.
            src, (surface, skirt_faces) = flat_colors.provoking_layout(len(positions), surface, skirt_faces)
            positions = np.ascontiguousarray(positions[src])
        if mesh_order.enabled() and len(faces):
            # Same triangles, drawn in an order the vertex cache reuses (render/mesh_order.py).
            perm, (surface, skirt_faces) = mesh_order.cache_order(positions, surface, skirt_faces)
            positions = np.ascontiguousarray(positions[perm])
            tcoords = None if tcoords is None else np.ascontiguousarray(tcoords[perm])
            colors = None if colors is None else np.ascontiguousarray(colors[perm])
        out.meshes.append(PreparedMesh(
            positions=positions, surface=surface, skirt=skirt_faces,
            tcoords=tcoords, texture=texture, colors=colors, name=mesh.name, provoking=provoking,
            double_sided=mesh.double_sided,
        ))
    return out


def prepare_tile(node: Any) -> tuple[PreparedTile, int]:
    """``load_fn`` for :class:`~citylod.lod.runtime.loader.TileLoader`: read and decode one tile.

    ``node`` is a render proxy (see :mod:`citylod.render.tileset_actor`) or a
    :class:`~citylod.io.tiles3d.Tile`; a proxy's ``tile`` attribute is the tile.

    Returns
    -------
    (PreparedTile, int)
        The arrays and the memory they hold in bytes (what the cache budget counts).
    """
    tile = getattr(node, "tile", node)
    content = tile.load_content()
    prepared = prepare_content(content, node.key, tile.level, str(tile.content_path or tile.key))
    return prepared, prepared.nbytes
