"""`abyss terrain | scene`: the world's terrain, and the scene a run left on shore."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from abyss.common.errors import BadMessage, ConfigError
from abyss.description.site import site_at
from abyss.interface.messages import (
    SceneUpdate,
    decode,
)


def cmd_terrain_build(args: argparse.Namespace) -> int:
    from abyss.stations.simulation import terrain

    site = site_at(args.site)
    if args.cloud is None:
        if site.seabed_cloud_file is None:
            raise ConfigError("--cloud", f"{site.file} names no model.seabed_cloud: give the cloud")
        args.cloud = site.seabed_cloud_file
    cloud = terrain.read_cloud(args.cloud)
    print(f"abyss: {len(cloud)} points from {args.cloud}; Poisson reconstruction ...", flush=True)
    built = terrain.reconstruct(cloud, depth=args.depth)
    print(
        f"abyss: surface of {built.vertices} vertices, {built.triangles} triangles; heights "
        f"{built.heights_m.min():.2f} to {built.heights_m.max():.2f} m on a "
        f"{terrain.GRID}x{terrain.GRID} grid"
    )
    if args.out is None:
        terrain.install(built.heights_m, site.directory, site.model_file)
        print(f"abyss: wrote {site.directory / 'terrain.bin'} and the terrain of {site.model_file}")
    else:
        args.out.mkdir(parents=True, exist_ok=True)
        terrain.write_hfield(built.heights_m, args.out / "terrain.bin")
        asset, geom = terrain.hfield_xml(built.heights_m, "terrain.bin")
        print(f"abyss: wrote {args.out / 'terrain.bin'}; in an MJCF beside it:\n  {asset}\n  {geom}")
    return 0


def cmd_terrain_cloud(args: argparse.Namespace) -> int:
    from abyss.stations.simulation import terrain

    terrain.write_cloud(terrain.fractal_cloud(args.seed, args.points), args.out)
    print(f"abyss: wrote {args.points} points of a fractal seabed (seed {args.seed}) to {args.out}")
    return 0


def cmd_scene_export(args: argparse.Namespace) -> int:
    from abyss.scene.export import SCENE_FILE, export

    source = args.run_dir / SCENE_FILE
    if not source.is_file():
        raise ConfigError(
            "RUN_DIR",
            f"{args.run_dir} holds no {SCENE_FILE}: not a run directory, "
            "or no scene reached shore in that run",
        )
    try:
        update = decode(str(source), source.read_bytes(), SceneUpdate).message
    except BadMessage as exc:
        raise ConfigError("RUN_DIR", f"{source}: {exc.reason}") from None
    for fmt in args.format:
        path = args.run_dir / f"scene.{fmt}"
        cells = export(update, path, fmt)
        print(f"abyss: wrote {path} ({cells} occupied cells at {update.resolution_m:g} m)")
    return 0


def add_commands(sub: Any) -> None:
    scene = sub.add_parser("scene", help="the scene a run left on shore").add_subparsers(
        dest="scene", required=True
    )
    p = scene.add_parser(
        "export", help="write the final octree as OctoMap .bt and a coloured point cloud .ply"
    )
    p.add_argument("run_dir", type=Path, metavar="RUN_DIR")
    p.add_argument(
        "--format",
        action="append",
        choices=("bt", "ply"),
        help="bt, ply, or both when repeated (default both)",
    )
    p.set_defaults(func=cmd_scene_export)
    terrain = sub.add_parser("terrain", help="seabed terrain from a point cloud").add_subparsers(
        dest="terrain", required=True
    )
    p = terrain.add_parser("build", help="reconstruct a surface (Open3D) and make it a site's terrain")
    p.add_argument(
        "cloud",
        nargs="?",
        type=Path,
        default=None,
        help="point cloud (.ply, .pcd, .xyz); default: the site's (model.seabed_cloud)",
    )
    p.add_argument(
        "--site",
        default="",
        metavar="DIR",
        help="the site package to build it into; the shipped one by default",
    )
    p.add_argument("--out", type=Path, help="write here instead of into the site's model")
    p.add_argument(
        "--depth", type=int, default=8, choices=range(5, 12), metavar="5..11", help="Poisson octree depth"
    )
    p.set_defaults(func=cmd_terrain_build)
    p = terrain.add_parser("cloud", help="write a seeded fractal seabed point cloud")
    p.add_argument("out", type=Path)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--points", type=int, default=20000)
    p.set_defaults(func=cmd_terrain_cloud)
