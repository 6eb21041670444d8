"""OGC 3D Tiles: tile content (:mod:`.content` writes glb; :mod:`.gltf` and :mod:`.legacy` read glTF and the
1.0 formats; :mod:`.colour` converts vertex colours) and the tileset document (:mod:`.tileset`), in a folder or a package (:mod:`.package`).

What a tile *is* lives here; what *makes* tiles lives in :mod:`citylod.lod.build`.
"""

from citylod.io.tiles3d.content import MeshData, PointData, TileContent, encode_glb, glb_buffer
from citylod.io.tiles3d.features import FeatureIdSet, PropertyTable
from citylod.io.tiles3d.gltf import decode_glb
from citylod.io.tiles3d.legacy import decode_content
from citylod.io.tiles3d.package import is_tileset_path
from citylod.io.tiles3d.tileset import (
    Tile,
    TileMesh,
    Tileset,
    TileSpec,
    content_path,
    open_tileset,
    safe_resolve,
    write_content,
    write_tileset,
)

__all__ = [
    "FeatureIdSet", "MeshData", "PointData", "PropertyTable", "Tile", "TileContent", "TileMesh", "TileSpec", "Tileset", "content_path",
    "decode_content", "decode_glb", "encode_glb", "glb_buffer", "is_tileset_path", "open_tileset", "safe_resolve", "write_content",
    "write_tileset",
]
