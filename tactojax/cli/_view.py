"""``tactojax view MAP... [--test DIR] [--estimates JSON] (--save FILE.rrd | --serve)``: a 3-D view in rerun."""

from __future__ import annotations


def add_parser(commands) -> None:
    parser = commands.add_parser(
        "view", help="interactive 3-D view of maps, touches, estimates and beliefs (rerun)",
        description="Log each map's contact cloud (coloured by height) and imprint frames in its object frame "
                    "(mm), a test dataset's touches at their true poses, and estimated against true sensor poses "
                    "with pose beliefs as weighted frames, to a rerun recording: saved as .rrd (open it with "
                    "`rerun FILE.rrd` or the web viewer) or served to rerun's web viewer on localhost. Needs the "
                    "`viz` extra (rerun-sdk).")
    parser.add_argument("maps", nargs="+", metavar="MAP", help="tactile maps (.npz) or map catalogs")
    parser.add_argument("--test", metavar="DIR", help="a dataset of test touches (e.g. from tactojax simulate)")
    parser.add_argument("--estimates", metavar="JSON",
                        help="estimates: a list of {object_id, T_object_sensor_wxyz_xyz, [T_object_sensor_true_"
                             "wxyz_xyz], [probability], [touch], [belief]} (tactojax localize / localize-live "
                             "--json are read too); see tactojax.viz._rerun")
    parser.add_argument("--model", default=None,
                        help="shape model for test touches without true heightmaps (a recording)")
    parser.add_argument("--voxel-mm", type=float, default=0.5, help="voxel size of the logged map clouds, mm")
    sink = parser.add_mutually_exclusive_group(required=True)
    sink.add_argument("--save", metavar="FILE.rrd", help="write the recording to a file")
    sink.add_argument("--serve", action="store_true",
                      help="serve it to rerun's web viewer on localhost until Ctrl-C")
    parser.add_argument("--web-port", type=int, default=9090, help="web viewer port with --serve (default 9090)")
    parser.add_argument("--grpc-port", type=int, default=9876, help="data port with --serve (default 9876)")
    parser.set_defaults(run=run)


def run(args) -> int:
    import time

    from tactojax.cli._table import format_table
    from tactojax.io import expand_catalogs, load_tactile_map
    from tactojax.viz import log_view, open_recording, read_estimates

    args.maps = expand_catalogs(args.maps)
    estimates = read_estimates(args.estimates) if args.estimates else []
    tactile_maps = [load_tactile_map(path) for path in args.maps]
    recording, url = open_recording(save=args.save, serve=args.serve, web_port=args.web_port,
                                    grpc_port=args.grpc_port)
    counts = log_view(recording, tactile_maps, test=args.test, estimates=estimates, model=args.model,
                      voxel_mm=args.voxel_mm)
    recording.flush()
    print(format_table(["logged", "count"], [[name.replace("_", " "), value] for name, value in counts.items()]))
    if args.save:
        recording.disconnect()
        print(f"recording: {args.save} (open with: rerun {args.save})")
        return 0
    print(f"web viewer: {url}  (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        return 0
