"""The volume verbs of ``pointfield cloud``: voxel grids, and drawing voxel files with ``cloud render``.

===============================  ==================================================
``pointfield cloud voxelize``    :func:`pointfield.volumes.voxelize_cloud` / ``voxelize_mesh``
``pointfield cloud sdf``         :func:`pointfield.volumes.mesh_to_sdf`, then :meth:`~pointfield.volumes.SDFGrid.to_mesh`
``pointfield cloud poisson``     :func:`pointfield.volumes.poisson_surface`
``cloud render X.binvox``        :meth:`pointfield.volumes.VoxelGrid.to_cloud`, drawn as a cloud (an OctoMap
                                 ``X.bt`` too: its occupied cells, ``read_octomap_grid``)
===============================  ==================================================
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pointfield.errors import PointfieldError
from pointfield.streaming.memory import DEFAULT_MEMORY, parse_memory


def add_commands(commands: argparse._SubParsersAction) -> None:
    """Add ``voxelize`` to the ``cloud`` subcommands."""
    voxelize = commands.add_parser(
        "voxelize",
        help="a voxel grid (.binvox, .vox, .npz) from a cloud or a mesh",
        description="Cut space into cubes of side --voxel from IN's minimum corner and write the occupied ones to "
        "OUT (.binvox, MagicaVoxel .vox, or .npz with every field). A cloud keeps per voxel its point count, "
        "mean colour and floating-point fields, and the majority of its labels; a mesh gives the voxels its "
        "surface passes through, and with --fill also those whose centre it encloses (generalized winding "
        "number > 1/2, which holds on meshes that are not quite closed).",
    )
    voxelize.add_argument("source", type=Path, metavar="IN", help="a point-cloud or mesh file")
    voxelize.add_argument("destination", type=Path, metavar="OUT", help=".binvox, .vox or .npz")
    voxelize.add_argument("--voxel", type=float, required=True, metavar="S", help="voxel side, in IN's units")
    voxelize.add_argument("--fill", action="store_true", help="a mesh: fill its inside too (solid voxels)")
    voxelize.add_argument(
        "--memory", metavar="SIZE", default=DEFAULT_MEMORY,
        help=f"memory the voxel work may take, e.g. 2G (default {DEFAULT_MEMORY}); a voxel too small for it "
        "is refused, naming the voxel that fits",
    )
    voxelize.add_argument("--device", metavar="NAME", help="where --fill's winding numbers run: auto, cpu, cuda, ...")
    voxelize.set_defaults(run=run_voxelize)

    sdf = commands.add_parser(
        "sdf",
        help="a mesh's signed distance field (.npz), and its zero level set as a closed mesh",
        description="Signed distances from IN's triangles at the nodes of a grid over its box (negative inside; "
        "the sign by the generalized winding number, so a mesh that is not quite closed still has an inside), "
        "written to OUT (.npz: sdf, origin, spacing). --mesh also writes the zero level set by marching cubes: "
        "one closed surface.",
    )
    sdf.add_argument("source", type=Path, metavar="IN", help="a mesh file (PLY, OFF, ...)")
    sdf.add_argument("destination", type=Path, metavar="OUT", help="the grid, .npz")
    size = sdf.add_mutually_exclusive_group()
    size.add_argument("--voxel", type=float, metavar="S", help="node spacing, in IN's units")
    size.add_argument("--resolution", type=int, metavar="N", help="nodes along the box's longest side (default 64)")
    sdf.add_argument("--mesh", type=Path, metavar="FILE", help="also write the zero level set as a mesh")
    sdf.add_argument("--memory", metavar="SIZE", default=DEFAULT_MEMORY,
                     help=f"memory the grid's work may take (default {DEFAULT_MEMORY})")
    sdf.add_argument("--device", metavar="NAME", help="auto, cpu, cuda, ...")
    sdf.set_defaults(run=run_sdf)

    poisson = commands.add_parser(
        "poisson",
        help="a watertight mesh through points with normals (Poisson reconstruction)",
        description="Solve Poisson's equation for the indicator function whose gradient matches IN's normals, on a "
        "grid of 2^depth cells across the points' box (grown by 1.1, as open3d and PoissonRecon), and write its "
        "level set through the points to OUT: one closed mesh. A cloud without normals gets them estimated "
        "(PCA, oriented away from the centroid), with a warning.",
    )
    poisson.add_argument("source", type=Path, metavar="IN", help="a cloud, with normals (nx ny nz) if it has them")
    poisson.add_argument("destination", type=Path, metavar="OUT", help="the mesh: .ply, .off, .obj or .glb")
    poisson.add_argument("--depth", type=int, default=8, help="2^depth cells across the box (default 8)")
    poisson.add_argument("--memory", metavar="SIZE", default="4G", help="memory the grid may take (default 4G)")
    poisson.set_defaults(run=run_poisson)


def may_hold_faces(path: Path) -> bool:
    """Whether ``path`` may be a mesh: a PLY whose header declares faces, or a file of a format that holds them (OFF)."""
    from pointfield.clouds.formats.ply import is_ply, parse_header
    from pointfield.clouds.formats.ply.header import HEADER_LIMIT
    from pointfield.clouds.formats.registry import format_of

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    with open(path, "rb") as file:
        head = file.read(HEADER_LIMIT)
    if is_ply(head):
        return any(e.name == "face" and e.count > 0 for e in parse_header(path, head).elements)
    return format_of(path).holds_faces


def run_voxelize(args: argparse.Namespace) -> int:
    import pointfield
    from pointfield.clouds.mesh import Mesh
    from pointfield.volumes import openness_text, voxelize_cloud, voxelize_mesh, write_voxels
    from pointfield.volumes.streamed import voxelize_file

    budget = parse_memory(args.memory)  # a bad size is an OptionError, printed as one line
    if not args.voxel > 0:
        raise PointfieldError(f"--voxel must be positive, got {args.voxel}")
    if args.destination.suffix.lower() not in (".binvox", ".vox", ".npz"):
        raise PointfieldError(f"{args.destination}: voxel grids are written as .binvox, .vox or .npz")
    # A file that may hold faces is read whole; a cloud a chunk at a time, so that one bigger than
    # memory voxelizes within --memory.
    data = pointfield.read(args.source) if may_hold_faces(args.source) else None
    if isinstance(data, Mesh) and len(data.faces):
        grid = voxelize_mesh(data, args.voxel, fill=args.fill, max_bytes=budget, device=args.device)
        note = f"; the mesh is {openness_text(grid.metadata['openness'])}"
        kind = "solid" if args.fill else "surface"
    else:
        if args.fill:
            raise PointfieldError(f"{args.source}: --fill needs a mesh (faces); this file holds points only")
        grid = voxelize_file(args.source, args.voxel, memory=budget) if data is None else voxelize_cloud(data, args.voxel)
        note = f" from {grid.metadata['points']:,} points"
        kind = "occupied"
    write_voxels(args.destination, grid)
    print(f"wrote {args.destination}: {len(grid):,} {kind} voxels of {args.voxel:g} in a "
          f"{' x '.join(map(str, grid.shape))} grid{note}")
    return 0


def run_sdf(args: argparse.Namespace) -> int:
    import pointfield
    from pointfield.clouds.mesh import Mesh
    from pointfield.geometry.meshes import MESH_SUFFIXES, write_mesh
    from pointfield.volumes import mesh_to_sdf, openness_text

    budget = parse_memory(args.memory)  # a bad size is an OptionError, printed as one line
    if args.voxel is not None and not args.voxel > 0:
        raise PointfieldError(f"--voxel must be positive, got {args.voxel}")
    if args.resolution is not None and args.resolution < 8:
        raise PointfieldError(f"--resolution must be at least 8, got {args.resolution}")
    if args.destination.suffix.lower() != ".npz":
        raise PointfieldError(f"{args.destination}: an SDF grid is written as .npz")
    if args.mesh is not None and args.mesh.suffix.lower() not in MESH_SUFFIXES:
        raise PointfieldError(f"{args.mesh}: a mesh is written as {', '.join(MESH_SUFFIXES)}")
    mesh = pointfield.read(args.source)
    if not isinstance(mesh, Mesh) or not len(mesh.faces):
        raise PointfieldError(f"{args.source}: no faces; a signed distance field needs a mesh")
    grid = mesh_to_sdf(mesh, voxel=args.voxel, resolution=args.resolution, max_bytes=budget, device=args.device)
    level_set = grid.to_mesh() if args.mesh else None
    grid.save(args.destination)
    print(f"wrote {args.destination}: {' x '.join(map(str, grid.shape))} signed distances, spacing {grid.spacing:.4g}; "
          f"the mesh is {openness_text(grid.metadata['openness'])}, and its winding number was ambiguous "
          f"(0.25..0.75) at {grid.metadata['ambiguous_nodes']:.1%} of the nodes where it was evaluated")
    if level_set is not None:
        write_mesh(args.mesh, level_set)
        print(f"wrote {args.mesh}: the zero level set, {len(level_set.faces):,} faces")
    return 0


def run_poisson(args: argparse.Namespace) -> int:
    import trimesh

    import pointfield
    from pointfield.geometry.meshes import MESH_SUFFIXES, write_mesh
    from pointfield.volumes import poisson_surface

    budget = parse_memory(args.memory)  # a bad size is an OptionError, printed as one line
    if args.destination.suffix.lower() not in MESH_SUFFIXES:
        raise PointfieldError(f"{args.destination}: a mesh is written as {', '.join(MESH_SUFFIXES)}")
    mesh = poisson_surface(pointfield.read(args.source), depth=args.depth, max_bytes=budget)
    write_mesh(args.destination, mesh)
    closed = trimesh.Trimesh(mesh.points, mesh.faces).is_watertight
    print(f"wrote {args.destination}: {len(mesh.faces):,} faces at depth {args.depth}, "
          f"{'watertight' if closed else 'NOT watertight'}")
    return 0


def run_render_voxels(args: argparse.Namespace) -> int:
    """``cloud render`` of a voxel file (or an OctoMap ``.bt``, its occupied cells): its voxel centres, drawn as a
    cloud with the voxels' fields."""
    from pointfield.viz.render import render_cloud, save_image
    from pointfield.volumes import read_voxels

    out = args.out or Path(args.file.with_suffix(".png").name)
    cloud = read_voxels(args.file).to_cloud()
    try:
        image = render_cloud(cloud, args.width, args.height, args.up, args.color_by, args.point_size)
    except PointfieldError as error:
        raise PointfieldError(f"{args.file}: {error}") from None
    save_image(out, image)
    print(f"wrote {out} ({args.width}x{args.height}, {len(cloud):,} voxel centres)")
    return 0
