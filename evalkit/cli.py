"""The `evalkit` command line.

Bad input (`InputError`) prints one line, ``evalkit: error: <source>: <problem>``, and exits 2;
``--verbose`` shows the traceback. With ``--json`` the last line on stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import traceback

from evalkit.errors import InputError


def _doctor(args) -> int:
    from evalkit.doctor import diagnose, report_lines

    results = diagnose()
    for line in report_lines(results):
        print(line)
    ok = all(r["ok"] for r in results.values())
    if args.json:
        print(json.dumps({"ok": ok, **results}))
    return 0 if ok else 1


def _scene_info(args) -> int:
    from evalkit.scene import load_scene

    scene = load_scene(args.scene)
    info = scene.summary()
    f = info["features"]
    print(f"scene       {info['name']}  ({info['source']})")
    print(f"triangles   {info['triangles']:,} in {info['meshes']} meshes, {info['degenerate_removed']} degenerate removed")
    print(f"bounds      {_vec(info['bounds']['min'])} .. {_vec(info['bounds']['max'])}, bounding radius {info['bounding_radius']:.4g}")
    print(f"area        {info['surface_area']:.6g}, depth complexity {f['depth_complexity']:.3f} surfaces per line")
    for m in info["materials"]:
        tex = f", texture {m['texture'][1]}x{m['texture'][0]}" if m["texture"] else ""
        emit = f", emission {_vec(m['emission'])}" if max(m["emission"]) > 0 else ""
        note = f" [{m['source_bsdf']}, approximated]" if m["approximated"] else ""
        print(f"material    {m['name']}: albedo {_vec(m['albedo'])}{tex}{emit}{', two-sided' if m['twosided'] else ''}{note}")
    for light in info["lights"]:
        print(f"light       {light['kind']}: {_vec(light['intensity'])}")
    c = info["camera"]
    print(f"camera      at {_vec(c['position'])}, fov {c['fov']:.4g} deg along {c['fov_axis']}, {c['width']}x{c['height']}")
    print(f"features    textures={f['textures']} emitters={f['emitters']} environment={f['environment']} "
          f"lights={','.join(f['light_types']) or '-'}")
    for w in info["warnings"]:
        print(f"warning     {w}")
    if args.json:
        print(json.dumps(info))
    return 0


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.4g}" for x in v) + ")"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="evalkit", description=__doc__.splitlines()[0])
    parser.add_argument("--verbose", action="store_true", help="show tracebacks")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("doctor", help="check GL (EGL), Mitsuba (+LLVM) and Embree; exit 1 with fixes if one is unusable")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_doctor)

    scene = sub.add_parser("scene", help="scene commands").add_subparsers(dest="scene_command", required=True)
    p = scene.add_parser("info", help="triangles, bounds, materials, lights, features and warnings of a scene")
    p.add_argument("scene", help="a built-in name (cornell-box, atrium, furnace) or a .xml/.obj/.ply/.gltf/.glb path")
    p.add_argument("--json", action="store_true")
    p.set_defaults(run=_scene_info)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.run(args)
    except InputError as e:
        if args.verbose:
            traceback.print_exc()
        print(f"evalkit: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("evalkit: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
