"""The commands around the stages (view, eval, convert, synth, demo, warmup): their parsers and thin ``_run_*``
functions; the work is in the package (``evaluate``, ``report``, ``io.convert``, ``synthetic``, ``demo``,
``warmup``)."""
from __future__ import annotations

import argparse

from .config import Ranged, add_config_arguments, command, config_from_args
from .options import OVERWRITE_FILE_HELP, OVERWRITE_HELP, _out_args


@command
def view(sub):
    from ..report import LIVE_MAX_FACES, PAGE_MAX_FACES

    p = sub.add_parser("view", help="look at a result: the mesh and the cameras in a browser (served on localhost)",
                       description="Serves an interactive 3D view of a result (its textured model, model.glb, when "
                                   "it has one, with a switch to the mesh; the cameras as frusta with their images) "
                                   "with viser on http://HOST:PORT until Ctrl-C; or, with --html FILE, "
                                   "writes a standalone viewer page (one file, no server, no network) and exits.")
    p.add_argument("result", help="result folder (OUT of 'reconstruct' or 'fuse') or a mesh file (never written to)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default: 127.0.0.1, this machine only)")
    p.add_argument("--port", type=Ranged(int, 0, 65535), default=8080, help="port (default: 8080; 0 = any free port)")
    p.add_argument("--max-faces", type=Ranged(int, 4, 2_000_000_000), default=None,
                   help=f"decimate larger meshes to this many faces (default: {LIVE_MAX_FACES:,} served, "
                        f"{PAGE_MAX_FACES:,} for --html)")
    p.add_argument("--lighting", choices=("environment", "plain"), default="environment",
                   help="environment: soft image-based light from all sides (default); plain: directional "
                        "lights only, quick to draw in a browser without a GPU")
    p.add_argument("--html", metavar="FILE", help="write a standalone viewer page to FILE instead of serving")
    p.add_argument("--overwrite", action="store_true", help="--html: " + OVERWRITE_FILE_HELP)
    p.set_defaults(func=_run_view)


def _run_view(args):
    import time

    from ..errors import BadArgumentError
    from ..report import (LIVE_MAX_FACES, PAGE_MAX_FACES, load_result, start_viewer_server, stop_viewer_server,
                         write_viewer_page)
    from ..report.result import result_model

    if args.max_faces is not None and args.max_faces < 4:
        raise BadArgumentError(f"--max-faces: expected >= 4, got {args.max_faces}")
    if not 0 <= args.port <= 65535:
        raise BadArgumentError(f"--port: expected 0-65535, got {args.port}")
    if args.html:
        from ..io.output import check_file_output

        check_file_output(args.html, args.overwrite, (args.result,), "--html")
    mesh, cameras, images = load_result(args.result)
    if args.html:
        path = write_viewer_page(args.html, mesh, cameras, title=f"photorecon: {args.result}",
                                 max_faces=args.max_faces or PAGE_MAX_FACES)
        print(f"view: {len(mesh.faces):,} faces, {len(cameras)} cameras -> {path} (open it in a browser)")
        return 0
    model = result_model(args.result)
    try:
        server = start_viewer_server(mesh, cameras, images, args.host, args.port, args.max_faces or LIVE_MAX_FACES,
                                     args.lighting, model)
    except OSError as exc:
        raise BadArgumentError(f"--host {args.host} --port {args.port}: cannot serve there ({exc})") from None
    host = server.get_host()
    shows = "the textured model (model.glb) and " if model is not None else ""
    print(f"view: {shows}{len(mesh.faces):,} faces, {len(cameras)} cameras at http://{host}:{server.get_port()} "
          "(Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    finally:
        stop_viewer_server(server)


@command
def eval_cmd(sub):
    p = sub.add_parser("eval", help="evaluate a mesh against ground truth (or poses against a reference)",
                       description="Mesh: accuracy, completeness, Chamfer, precision/recall/F-score at each tau "
                                   "(default 1%% and 0.5%% of the truth's diagonal), normal consistency; "
                                   f"{200_000} area-uniform samples per mesh, seed 0. A --gt with vertices and no "
                                   "faces is a reference point cloud (DTU / ETH3D / Tanks-and-Temples style): per "
                                   "tau, accuracy = fraction of result samples within tau of a reference point, "
                                   "completeness = fraction of reference points within tau of the result, F-score. "
                                   "A result with cameras beside it (a reconstruct output's sparse/0) is first moved "
                                   "into the truth's frame through the cameras (see --align-poses).")
    p.add_argument("--mesh", help="result mesh (or point cloud, against a point-cloud --gt)")
    p.add_argument("--gt", help="ground truth: a mesh, or a point cloud (PLY with vertices and no faces)")
    p.add_argument("--tau", type=Ranged(float, 0.0, None, exclusive_min=True, sep=True), metavar="T[,T...]",
                   help="distance thresholds in scene units, e.g. 0.0005,0.001,0.002 (default: 1%%,0.5%% of the "
                        "GT's bounding-box diagonal); with a mesh GT the first is the headline tau")
    p.add_argument("--crop-to-reference", type=Ranged(float, 0.0, None), metavar="MARGIN",
                   help="ignore result samples farther than MARGIN (scene units) from the GT's bounding box: "
                        "background the reference does not cover; completeness is unaffected")
    p.add_argument("--icp", action="store_true", help="refine the result onto the truth with ICP first")
    p.add_argument("--align-poses", action=argparse.BooleanOptionalAction, default=None,
                   help="move the result into the truth's frame with the similarity that aligns its cameras to the "
                        "truth's (same image names; cameras from --poses/--ref, else sparse/0 or transforms.json "
                        "beside each file); default: when both sides have cameras")
    p.add_argument("--poses", help="estimated cameras: COLMAP folder or transforms.json")
    p.add_argument("--ref", help="reference cameras: COLMAP folder or transforms.json")
    p.add_argument("--json", dest="json_out", nargs="?", const="-", help="print JSON (or write it to a file)")
    p.add_argument("--error-mesh", help="write the result coloured by error to this PLY (and a PNG next to it)")
    p.add_argument("--overwrite", action="store_true", help=OVERWRITE_FILE_HELP)
    p.set_defaults(func=_run_eval)


def _run_eval(args):
    import json
    from pathlib import Path

    from ..evaluate import EvalRequest, evaluate, format_report
    from ..io.atomic import atomic_write_text
    from ..io.output import check_file_output

    written = [("--json", args.json_out)]
    if args.error_mesh:  # the coloured mesh and its picture
        written += [("--error-mesh", args.error_mesh), ("--error-mesh", Path(args.error_mesh).with_suffix(".png"))]
    for flag, dst in written:
        check_file_output(dst, args.overwrite, (args.mesh, args.gt, args.poses, args.ref), flag)
    report = evaluate(EvalRequest(mesh=args.mesh, gt=args.gt, tau=args.tau, crop_to_reference=args.crop_to_reference,
                                  icp=args.icp, align_poses=args.align_poses, poses=args.poses, ref=args.ref,
                                  error_mesh=args.error_mesh, quiet_json=args.json_out == "-"))
    if args.json_out:
        text = json.dumps(report, indent=2)
        if args.json_out == "-":
            print(text)
        else:
            atomic_write_text(args.json_out, text + "\n")
    if args.json_out != "-":
        print(format_report(report))
    return 0


@command
def convert(sub):
    p = sub.add_parser("convert", help="convert cameras between COLMAP, transforms.json, NeRF Blender, NeuS, LLFF "
                                       "and PyTorch3D",
                       description="SRC: COLMAP folder (text or binary), dataset folder, transforms.json or "
                                   "transforms_SPLIT.json (NeRF Blender), cameras_sphere.npz (IDR/NeuS, images in "
                                   "image/ beside it), poses_bounds.npy (LLFF, images in images/ beside it). "
                                   "DST: a folder (COLMAP), a .json file (transforms.json; NeRF Blender when named "
                                   "transforms_train|val|test.json; PyTorch3D with --to pytorch3d), a .npz (NeuS) "
                                   "or a .npy (LLFF). NeuS and LLFF pair camera i with the i-th sorted image.")
    p.add_argument("src")
    p.add_argument("dst")
    from ..io.convert import formats

    p.add_argument("--to", choices=formats(), default="auto",  # the camera format registry, io.cameras
                   help="output format (default: from DST: folder -> colmap-text, .json -> transforms or blender, "
                        ".npz -> neus, .npy -> llff)")
    p.add_argument("--world", choices=["none", "nerfstudio", "instant-ngp"], default="none",
                   help="transforms.json world orientation to write (default: none = photorecon's world)")
    p.add_argument("--src-world", choices=["none", "nerfstudio", "instant-ngp"], default=None,
                   help="world orientation of a transforms.json SRC (default: as recorded in the file)")
    p.add_argument("--neus-world", choices=["normalized", "original"], default="normalized",
                   help="world of a NeuS SRC: normalized (world_mat @ scale_mat, the unit-sphere frame NeuS trains "
                        "in; default) or original (world_mat alone)")
    p.add_argument("--bounds", nargs=2, type=Ranged(float, 0.0, None, exclusive_min=True), metavar=("NEAR", "FAR"),
                   help="LLFF output: near and far depth for every image (default: from the sparse points)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing DST file; a DST folder: " + OVERWRITE_HELP)
    p.set_defaults(func=_run_convert)


def _run_convert(args):
    from ..io.convert import convert_cameras, writes_folder
    from ..io.output import check_file_output, output_folder

    def write():
        return convert_cameras(args.src, args.dst, args.to, args.world, args.src_world, args.neus_world,
                               tuple(args.bounds) if args.bounds else None)

    from pathlib import Path

    if writes_folder(args.to, Path(args.dst)):  # a COLMAP folder
        with output_folder(args.dst, args.overwrite, inputs=(args.src,), command="convert", resumable=False):
            dst = write()
    else:
        check_file_output(args.dst, args.overwrite, (args.src,), "DST", may_hold=(args.src,))  # a new file in SRC
        dst = write()
    print(f"convert: {args.src} -> {dst}")
    return 0


@command
def synth(sub):
    from ..synthetic import SynthConfig

    p = sub.add_parser("synth", help="render a mesh or built-in scene to images, depth, masks and cameras",
                       description="Render a synthetic dataset with ground truth (see the README for the layout).")
    _out_args(p)
    add_config_arguments(p, SynthConfig)
    p.set_defaults(func=_run_synth)


def _run_synth(args):
    from ..synthetic import SynthConfig, synthesize

    cfg = config_from_args(SynthConfig, args)
    res = synthesize(cfg, args.out, overwrite=args.overwrite)
    print(f"synth: {len(res.views)} views, {res.seconds_per_view:.3f} s/view -> {res.root}")
    return 0


@command
def demo(sub):
    from ..demo import DemoConfig

    p = sub.add_parser("demo", help="the built-in demo: synthesize a scene, reconstruct it, measure it",
                       description="Renders a textured scene, reconstructs it from its images alone (SfM + MVS + "
                                   "TSDF) and prints accuracy against the ground truth. --scene bunny: the original "
                                   "article's experiment (the Stanford bunny from a ring of cameras, rendered depth, "
                                   "meshed three ways side by side).")
    p.add_argument("-o", "--out", default="photorecon_demo", help="output folder (default: ./photorecon_demo)")
    p.add_argument("--overwrite", action="store_true", help="allow a non-empty folder not made by photorecon")
    add_config_arguments(p, DemoConfig)
    p.set_defaults(func=_run_demo)


def _run_demo(args):
    from pathlib import Path

    from ..demo import DemoConfig, print_bunny_summary, print_summary, run_bunny_demo, run_demo

    cfg = config_from_args(DemoConfig, args)
    if cfg.scene == "bunny":
        print_bunny_summary(run_bunny_demo(args.out, cfg, overwrite=args.overwrite), Path(args.out))
        return 0
    s = run_demo(args.out, cfg, overwrite=args.overwrite)
    print_summary(s, Path(args.out))
    return 0


@command
def warmup(sub):
    p = sub.add_parser("warmup", help="compile the numba kernels once, into numba's cache (tools/install.sh runs it)",
                       description="Compiles every compiled kernel (PatchMatch, TSDF) on a tiny synthetic scene, so "
                                   "numba's cache holds them (the __pycache__ folders next to the package's modules, "
                                   "or NUMBA_CACHE_DIR) and later runs load them instead of compiling them.")
    p.set_defaults(func=_run_warmup)


def _run_warmup(args):
    from ..warmup import warm_up

    r = warm_up()
    how = (f"{len(r['compiled'])} compiled, {len(r['cached'])} already in numba's cache" if r["compiled"]
           else "all already in numba's cache")
    print(f"warmup: {r['kernels']} kernels ({how}) in {r['seconds']:.1f} s")
    if r["missing"]:
        print("  not reached (compiled on first use instead): " + ", ".join(r["missing"]))
    return 0
