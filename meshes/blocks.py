"""A square block with one embedded crack segment (the shear-fracture scenario's mesh)."""
from __future__ import annotations

import numpy as np

from .gmsh_util import build_mesh


def square_with_segment(comm, half_size: float, p0, p1, h: float, block_tag: int, crack_tag: int,
                        left_tag: int, other_tag: int):
    """The square [-R, R]^2 meshed at uniform size ``h`` with the segment p0 -> p1 embedded
    as interior facets.  Facet tags: ``crack_tag`` on the segment, ``left_tag`` on the side
    x = -R, ``other_tag`` on the other three sides.  Returns (mesh, facet tags)."""
    R = float(half_size)

    def build(model):
        import gmsh
        occ = model.occ
        square = occ.addRectangle(-R, -R, 0.0, 2 * R, 2 * R)
        a, b = occ.addPoint(*np.asarray(p0, float), 0.0), occ.addPoint(*np.asarray(p1, float), 0.0)
        crack = occ.addLine(a, b)
        occ.synchronize()
        model.mesh.embed(1, [crack], 2, square)
        left, other = [], []
        for _, curve in model.getBoundary([(2, square)], oriented=False):
            xc = occ.getCenterOfMass(1, abs(curve))[0]
            (left if abs(xc + R) < 1e-6 * R else other).append(abs(curve))
        model.addPhysicalGroup(2, [square], block_tag)
        model.addPhysicalGroup(1, [crack], crack_tag)
        model.addPhysicalGroup(1, left, left_tag)
        model.addPhysicalGroup(1, other, other_tag)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMax", h)
        gmsh.option.setNumber("Mesh.CharacteristicLengthMin", h)

    mesh, _, facet_tags = build_mesh(comm, build, name="square_with_segment")
    return mesh, facet_tags
