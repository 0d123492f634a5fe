"""``evsmap reproduce``: the main job. Expands the paper's Tables I-IV into cells, measures every
cell that can be measured on this machine (the rest say what they need), stores one record per
cell and writes the report folder: one Markdown and one CSV file per table with the paper's value
beside each measured one, an index and plots.

This module parses and checks the options (one line and exit 2 for a bad one, before anything is
written); the run itself is :func:`evsmap.runner.reproduce.reproduce`'s."""

from __future__ import annotations

import argparse
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

from evsmap.cli.options import positive_float, positive_int
from evsmap.cli.outputs import Output, check_writable
from evsmap.cli.precision import check_device, device_arg
from evsmap.errors import DataFormatError, EvsmapError

if TYPE_CHECKING:
    from evsmap.runner.reproduce import Reproduction
    from evsmap.runner.runfile import RunFile, RunSettings


def _tables(text: str) -> list[str]:
    from evsmap.tables.schema import table_numbers

    numbers = table_numbers()
    out = []
    for part in text.split(","):
        name = part.strip().upper()
        if name not in numbers:
            raise argparse.ArgumentTypeError(
                f"unknown table {part.strip()!r} (choose from {', '.join(numbers)})")
        if numbers[name] not in out:
            out.append(numbers[name])
    return out


def _cells(text: str) -> list[str]:
    out = [g.strip() for g in text.split(",") if g.strip()]
    if not out:
        raise argparse.ArgumentTypeError("no cell pattern given")
    return list(dict.fromkeys(out))


def _models(text: str) -> list[str]:
    from evsmap.registry import SEGMENTERS

    out = [m.strip() for m in text.split(",") if m.strip()]
    for m in out:
        if m not in SEGMENTERS.names():
            raise argparse.ArgumentTypeError(f"unknown segmenter {m!r}")
    if not out:
        raise argparse.ArgumentTypeError("no model given")
    return list(dict.fromkeys(out))


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "reproduce", help="measure the paper's Tables I-IV and write a report folder",
        description="Measure every cell of the paper's Tables I-IV that this machine can "
                    "measure (parameters, FLOPs and CPU speed of every network; mapping rate "
                    "and map size of every system on the built-in synthetic sequence and the "
                    "real TUM sample; mIoU where prepared datasets and trained weights are "
                    "given) and write reports/<run>/ with the paper's value beside every "
                    "measured one. Cells that cannot be measured say what they need.")
    _add_what(p)
    _add_where(p)
    _add_resume_and_passes(p)
    p.set_defaults(run=run)


def _add_what(p: argparse.ArgumentParser) -> None:
    """What the run measures, from which data."""
    p.add_argument("--tables", type=_tables, default=None,
                   metavar="LIST", help="tables to reproduce, e.g. I,IV (default I,II,III,IV; "
                                        "with --resume, those of the run)")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="run folder (default reports/<UTC date-time>)")
    p.add_argument("--data-root", type=Path, metavar="DIR",
                   help="where prepared datasets (nyuv2/, sunrgbd/, cityscapes/) and mapping "
                        "sequences (tum_fr1_xyz/, rtabmap.bag, asl.bag, ours1.bag, ours2.bag) "
                        "are found (default $EVSMAP_DATA_ROOT or ../shared/data; datasets/ is "
                        "always searched too)")
    p.add_argument("--weights", "--weights-dir", dest="weights_dir", type=Path, metavar="DIR",
                   help="a folder of trained weights named <segmenter>@<dataset>.pt, e.g. "
                        "feagnet-v2@nyuv2.pt: the mIoU cells and the maps with a network's "
                        "classes need them (speed and complexity do not: they run each "
                        "network's random initialisation, seed 0, stated in the records)")
    p.add_argument("--quick", action=argparse.BooleanOptionalAction, default=None,
                   help="smoke test (under 3 minutes): 8 frames at 320x240, speed timed with "
                        "torch for a 3 s budget per cell (3 passes at least), speed cells above "
                        "1024x512 skipped (with --resume: as the run was made)")
    p.add_argument("--extended", action=argparse.BooleanOptionalAction, default=None,
                   help="also map Table IV's systems on the long synthetic sequence (640 "
                        "frames, 4 laps with revisits: the map growth and the Map Size "
                        "readings' check), at 5 cm beside 2 cm, and the C++ OctoMap on the "
                        "synthetic room: 33 more mapping runs, 16 of them of 640 frames (not "
                        "timed as a whole; with --resume: as the run was made)")
    p.add_argument("--scannet-scenes", type=_scenes, default=None, metavar="LIST",
                   help="ScanNet scenes the semantic-detail section maps, e.g. "
                        "scene0011_00,scene0015_00, from <data root>/scannet/scans/ (default: "
                        "the first two of the validation split there; without ScanNet the "
                        "section maps the synthetic room and says what is missing)")
    p.add_argument("--scannet-step", type=positive_int, default=None, metavar="N",
                   help="map every N-th frame of a ScanNet scene (default 10: 3 Hz of its "
                        "30 Hz)")
    p.add_argument("--synthetic-labels", choices=("oracle", "network"), default=None,
                   help="what labels Table IV's semantic rows map the synthetic room with where "
                        "their network has no NYUv2 weights: oracle (default: ground truth with "
                        "the --oracle-profile noise) or network (a trained proxy network's own: "
                        "the first of feagnet-v1, feagnet-v2, fchardnet-70 with synthrooms "
                        "weights in --weights, e.g. feagnet-v1@synthrooms.pt or from --train; "
                        "n/a naming the weights without one). The semantic-detail section maps "
                        "the room with every other source beside it (with --resume: the run's)")
    p.add_argument("--oracle-profile", type=_oracle_profile, default=None,
                   metavar="NAME|FILE",
                   help="the oracle's profile where it stands in for a network: fitted "
                        "(default), per-pixel, noise-free, or a profile file (`evsmap oracle "
                        "fit`; docs/oracle.md) (with --resume: the run's)")
    p.add_argument("--budget", type=positive_float, default=None, metavar="MINUTES",
                   help="fit the run into this many minutes: a cell whose estimated time no "
                        "longer fits is not started and is recorded as not measured, with the "
                        "reason (the cells the paper's claims rest on run first); the estimate "
                        "is printed at the start")
    p.add_argument("--cells", type=_cells, default=None, metavar="GLOBS",
                   help="only the cells whose key matches one of these comma-separated globs, "
                        "e.g. 'table1/feagnet-*/complexity*' (keys as in records/*.json; a "
                        "Table IV cell brings its mapping runs); default: every cell of "
                        "--tables (with --resume: the run's)")


def _oracle_profile(text: str) -> str:
    """A shipped profile's name as given, a profile file as its absolute path (so a resumed
    run finds it from anywhere); one line naming the problem when it is neither."""
    from evsmap.segmenters.oracle_profile import PROFILE_NAMES, load_profile

    try:
        load_profile(text)
    except EvsmapError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text if text in PROFILE_NAMES else str(Path(text).expanduser().resolve())


def _scenes(text: str) -> list[str]:
    from evsmap.readers.scannet.labelmap import SCENE_ID

    scenes = [t.strip() for t in text.split(",") if t.strip()]
    bad = [s for s in scenes if not SCENE_ID.match(s)]
    if not scenes or bad:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated scene ids such as scene0011_00, got {text!r}")
    return scenes


def _add_where(p: argparse.ArgumentParser) -> None:
    """Where and how the cells run, and the user's systems."""
    p.add_argument("--workers", type=positive_int, default=None, metavar="N",
                   help="processes for the cells that are not timed (default 2; with --resume, "
                        "the run's); timed cells "
                        "always run alone, each in a fresh process (with --executor ray: not "
                        "used, each cell reserves the CPUs it uses)")
    p.add_argument("--executor", choices=("local", "ray"), default=None,
                   help="where the cells run: local (default, or the resumed run's: process "
                        "pools on this machine) "
                        "or ray (a Ray cluster, pip install \"evsmap[ray]\"): cells that are "
                        "not timed run as tasks on any node, each timed cell alone on a whole "
                        "node (docs/runner.md)")
    p.add_argument("--address", default=None, metavar="ADDR",
                   help="with --executor ray: the cluster to join (HOST:6379, or auto); "
                        "default: start a local Ray cluster with this machine's CPUs")
    p.add_argument("--strict-timing", action=argparse.BooleanOptionalAction, default=None,
                   help="refuse to time on a busy machine: stop at once when the load average "
                        "exceeds the cores, and record a speed cell whose calibration shows "
                        "contention (twice) as not measured instead of flagging it")
    p.add_argument("--systems", type=Path, default=None, metavar="FILE",
                   help="with Table IV: a TOML file of your own mapping systems (registered "
                        "updaters and segmenters, e.g. plug-ins) mapped beside the paper's on "
                        "the same sequences; see docs/plugins.md (with --resume: the run's)")


def _add_resume_and_passes(p: argparse.ArgumentParser) -> None:
    """Resuming, and the opt-in passes (proxy training, int8)."""
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out (after Ctrl-C, a failure or a crash): keep "
                        "its finished cells, run the rest, with the run's own settings (tables, "
                        "--quick, --cells, --systems, --train, --precision, data and weights "
                        "folders, executor, workers) unless given again")
    p.add_argument("--force", action="store_true",
                   help="with --resume: run every cell again")
    p.add_argument("--train", action=argparse.BooleanOptionalAction, default=None,
                   help="opt-in, long: train the missing proxy weights on evsmap's synthetic "
                        "rooms (synthrooms, prepared if missing) and report their mIoU and, "
                        "with Table IV, TFEAGMap's and EVSMap's maps made with the trained "
                        "network, in 'Synthetic proxy' sections (never in the paper's columns); "
                        "weights go to --weights DIR (default ~/.cache/evsmap/weights; with "
                        "--quick, the run's cache)")
    p.add_argument("--proxy-models", type=_models, default=None, metavar="LIST",
                   help="with --train: networks to train (default "
                        "feagnet-v1,feagnet-v2,fchardnet-70)")
    p.add_argument("--proxy-recipe", default=None, metavar="NAME",
                   help="with --train: training recipe (default synth-proxy)")
    p.add_argument("--device", type=device_arg, default=None, metavar="DEVICE",
                   help="where the speed cells time the networks: cpu (default) or cuda[:N] "
                        "(torch on the GPU, CUDA events, a warm-up until the speed settles; "
                        "the cells' notes and records name the GPU; the map updates stay on "
                        "the CPU; docs/gpu.md; with --resume, the run's)")
    p.add_argument("--precision", choices=("fp32", "int8"), default=None,
                   help="int8: also measure every network with a speed cell in int8 beside "
                        "fp32 (ONNX Runtime static QDQ, the scheme auto picks for this CPU: "
                        "speed-up, top-1 agreement, mIoU "
                        "where weights and data are here), in an 'int8 beside fp32' section of "
                        "Tables I-III and int8.csv; the paper's cells stay fp32 (default fp32; "
                        "with --resume, the run's)")


def run(args: argparse.Namespace) -> int:
    from evsmap.report.build import build_report
    from evsmap.runner.reproduce import reproduce

    job = _reproduction(args)
    job.count_startup = True
    records = reproduce(job)
    t0 = time.perf_counter()
    written = build_report(job.out)
    report_s = time.perf_counter() - t0
    ok = sum(r.status == "ok" for r in records)
    na = sum(r.status == "na" for r in records)
    err = [r for r in records if r.status == "error"]
    print(f"{len(records)} cells: {ok} measured, {na} n/a (need data, weights or a Jetson), "
          f"{len(err)} failed")
    for r in err[:10]:
        print(f"  failed: {r.key}: {r.error}")
    print(f"report written to {job.out}/ ({', '.join(p.name for p in written[:6])}, ...) in "
          f"{report_s:.1f} s")
    return 1 if err else 0


def _reproduction(args: argparse.Namespace) -> Reproduction:
    """The run the options ask for, checked (one-line errors) before anything is written."""
    from evsmap.runner.matrix import make_executor
    from evsmap.runner.reproduce import Reproduction, user_systems
    from evsmap.runner.runfile import RUN_FILE
    from evsmap.tables.schema import table_ids

    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    out = args.out or Path("reports") / stamp
    if args.force and not args.resume:
        raise EvsmapError("--force only applies with --resume (a new run measures everything)")
    previous = _resumed(args, out) if args.resume else None
    if previous is not None:
        stamp = previous.run or stamp
    elif out.exists() and any(out.iterdir()):
        raise EvsmapError(f"--out {out}: folder exists and is not empty (use --resume to "
                          f"continue a run there)")
    check_writable(Output("--out", out, folder=True, in_place=True))  # before minutes of work
    settings = _settings(args, out)
    tables = args.tables if args.tables is not None else list(table_ids())
    # checked before anything is written: an unknown or missing executor is a usage error
    executor = make_executor(settings.executor, address=settings.address)
    systems = user_systems(args.systems, tables, previous, out / RUN_FILE)
    _check_machine(settings)
    return Reproduction(out=out, stamp=stamp, tables=tables, settings=settings,
                        systems=systems, executor=executor, resume=args.resume,
                        force=args.force)


def _resumed(args: argparse.Namespace, out: Path) -> RunFile:
    """The run in ``out`` that ``--resume`` continues; fills the settings not given with its
    own (``args``) and refuses what would change what it measures."""
    from evsmap.runner.runfile import RUN_FILE, RunFile

    path = out / RUN_FILE
    if not path.is_file():
        raise EvsmapError(f"--resume: {out} holds no run ({RUN_FILE} missing)")
    try:
        previous = RunFile.read(path)
    except DataFormatError as exc:
        raise EvsmapError(f"--resume: {exc}") from None
    _resume_settings(args, previous.stored_settings(), path)
    if args.tables is not None and args.tables != previous.tables:
        raise EvsmapError(f"--resume: the run in {out} covers tables "
                          f"{', '.join(previous.tables)}; resume it without --tables (or with "
                          f"the same list)")
    args.tables = previous.tables
    if args.systems is not None:
        raise EvsmapError(f"--resume: a resumed run keeps its systems ({len(previous.systems)} "
                          f"stored in {path}); resume it without --systems")
    return previous


def _settings(args: argparse.Namespace, out: Path) -> RunSettings:
    """The run's settings: those given, else the defaults; checked."""
    from evsmap.runner.runfile import RunSettings

    given = {name: getattr(args, name) for name in RunSettings.model_fields
             if getattr(args, name) is not None}
    settings = RunSettings(**given)
    if not settings.train and (settings.proxy_models is not None
                               or settings.proxy_recipe is not None):
        raise EvsmapError("--proxy-models and --proxy-recipe only apply with --train")
    if settings.train and settings.weights_dir is None:
        from evsmap.runner.proxy import default_weights_dir

        # a --quick run's 1-epoch weights stay in its own folder
        settings.weights_dir = (out / "cache" / "weights" if settings.quick
                                else default_weights_dir())
        settings.weights_dir.mkdir(parents=True, exist_ok=True)
    if settings.weights_dir is not None and not settings.weights_dir.is_dir():
        raise EvsmapError(f"--weights {settings.weights_dir}: no such folder")
    return settings


def _check_machine(settings: RunSettings) -> None:
    """The data folder exists; the device is here; with ``--strict-timing``, the machine is
    idle."""
    if settings.data_root is not None and not settings.data_root.is_dir():
        raise EvsmapError(f"--data-root {settings.data_root}: no such folder")
    check_device(settings.device, settings.precision)
    if settings.strict_timing:
        import os

        load1 = os.getloadavg()[0]
        cores = os.cpu_count() or 1
        if load1 > cores:
            raise EvsmapError(f"--strict-timing: the machine is busy (load average {load1:.1f} "
                              f"on {cores} cores); wait until it is idle or drop "
                              f"--strict-timing (busy cells are then flagged)")


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _resume_settings(args: argparse.Namespace, stored: dict[str, Any], source: Path) -> None:
    """Fill the settings not given with the resumed run's (``stored``); refuse a given one
    that would change what the run measures."""
    from evsmap.runner.runfile import FIXED_SETTINGS

    for name, value in stored.items():
        given = getattr(args, name)
        if given is None:
            setattr(args, name, value)
        elif name in FIXED_SETTINGS and given != value:
            if isinstance(value, bool):
                made = f"{'with' if value else 'without'} {_flag(name)}"
            else:
                made = f"with {_flag(name)} {value if value is not None else '(not given)'}"
            raise EvsmapError(f"--resume: the run in {source.parent} was made {made}; resume "
                              f"it without {_flag(name)} (a resumed run keeps what it "
                              f"measures)")
