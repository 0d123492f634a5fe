"""``evsmap datasets``: prepare the segmentation datasets (NYUv2, SUN RGB-D, Cityscapes) from
their official files or render the synthetic one (synthrooms), list the prepared ones, and fetch
the real sample data."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from evsmap.cli.options import nonnegative_int, positive_int
from evsmap.datasets import DATASETS, get_preparer
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.progress import progress

DEFAULT_ROOT = Path("datasets")

_SOURCES = {
    "nyuv2": "folder with nyu_depth_v2_labeled.mat, splits.mat, classMapping40.mat",
    "sunrgbd": "folder with SUNRGBD/ and SUNRGBDtoolbox/",
    "cityscapes": "folder with leftImg8bit/, gtFine/, disparity/, camera/",
}
GENERATED = {"synthrooms": "synthetic rooms of every type rendered by evsmap, NYUv2 40 classes, "
                           "split into train/val/test by room"}
"""Datasets that ``prepare`` renders itself (no ``--from``)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "datasets", help="prepare segmentation datasets (NYUv2, SUN RGB-D, Cityscapes), list "
                         "them; fetch the real sample data",
        description="Convert the official files of a segmentation dataset into the layout "
                    "evsmap reads (see datasets/README.md), list the prepared datasets, or fetch "
                    "the real sample data the tests and `evsmap reproduce` use.")
    dsub = p.add_subparsers(dest="datasets_command", metavar="SUBCOMMAND",
                            parser_class=type(p))
    dsub.required = True
    _add_prepare(dsub)
    _add_list(dsub)
    _add_check(dsub)
    _add_fetch(dsub)


def _add_prepare(dsub: argparse._SubParsersAction) -> None:
    prep = dsub.add_parser(
        "prepare", help="convert a dataset's official files",
        description="Read the official files of DATASET from --from and write the prepared "
                    "layout to --out (written completely or not at all). Sources: "
                    + "; ".join(f"{k}: {v}" for k, v in _SOURCES.items()) + ". synthrooms "
                    "takes no --from: it renders --rooms procedural rooms (bedroom, living "
                    "room, office, kitchen in turn, each its own layout and camera path) with "
                    "Kinect-like depth noise, --frames-per-room views each, and splits them "
                    "into train/val/test by room (the same options give the same bytes).")
    names = sorted([*DATASETS, *GENERATED])
    prep.add_argument("dataset", choices=names, metavar="DATASET",
                      help=f"one of {', '.join(names)}")
    prep.add_argument("--from", dest="source", type=Path, metavar="DIR",
                      help="folder holding the official files (not for synthrooms)")
    prep.add_argument("--out", type=Path, metavar="DIR",
                      help="output folder (default: datasets/<DATASET> under the current folder)")
    prep.add_argument("--limit", type=positive_int, metavar="N",
                      help="prepare only the first N frames of each split (a quick check)")
    prep.add_argument("--overwrite", action="store_true",
                      help="replace a non-empty output folder (only once the new one is complete)")
    prep.add_argument("--raw-depth", action="store_true",
                      help="sunrgbd only: use the raw depth/ images instead of the refined "
                           "depth_bfx/")
    from evsmap.datasets import synthrooms as sr

    h, w = sr.DEFAULT_SIZE
    per_split = ", ".join(f"{len(v)} {k}" for k, v in sr.split_rooms(sr.DEFAULT_ROOMS).items())
    prep.add_argument("--rooms", type=positive_int, metavar="N",
                      help=f"synthrooms: number of rooms, at least {sr.MIN_ROOMS} (default "
                           f"{sr.DEFAULT_ROOMS}: {per_split} rooms)")
    prep.add_argument("--frames-per-room", type=positive_int, metavar="M",
                      help=f"synthrooms: views per room over one lap of its camera path "
                           f"(default {sr.DEFAULT_FRAMES_PER_ROOM})")
    prep.add_argument("--size", metavar="HxW",
                      help=f"synthrooms: image height x width in pixels (default {h}x{w}, half "
                           "the Kinect resolution, what the synth-proxy training uses)")
    prep.add_argument("--seed", type=nonnegative_int, metavar="S",
                      help=f"synthrooms: seed of the room layouts, camera paths and noise "
                           f"(default {sr.DEFAULT_SEED})")
    prep.set_defaults(run=run_prepare)


def _add_list(dsub: argparse._SubParsersAction) -> None:
    lst = dsub.add_parser(
        "list", help="list prepared datasets under a data root",
        description="List the prepared datasets (folders with evsmap-dataset.json, or layouts a "
                    "dataset reader recognises) directly under --root; with none there (or no "
                    "datasets/ folder yet), the datasets evsmap reads and how to prepare them.")
    lst.add_argument("--root", type=Path, metavar="DIR",
                     help="data root (default: datasets/ under the current folder)")
    lst.add_argument("--json", action="store_true", help="print the list as JSON")
    lst.set_defaults(run=run_list)


def _add_check(dsub: argparse._SubParsersAction) -> None:
    check = dsub.add_parser(
        "check", help="check a copy of a dataset evsmap cannot download (ScanNet)",
        description="ScanNet needs a signed agreement, so evsmap does not download it: this "
                    "says how to obtain it and where to put it, and checks a copy in the "
                    "release layout (scans/sceneNNNN_NN/ with the .sens and "
                    "_vh_clean_2.labels.ply, scannetv2-labels.combined.tsv, the split files): "
                    "every file present and readable, frames and vertices counted, one line "
                    "per problem. Exit 0: no problem; 1: problems (listed); 2: no copy there.")
    check.add_argument("dataset", choices=["scannet"], metavar="DATASET", help="scannet")
    check.add_argument("--root", type=Path, metavar="DIR",
                       help="the release folder (default: scannet/ under the data root, "
                            "$EVSMAP_DATA_ROOT or ../shared/data, or under datasets/)")
    check.add_argument("--no-meshes", action="store_true",
                       help="do not read the labelled meshes (faster; their presence is "
                            "still checked)")
    check.add_argument("--json", action="store_true", help="print the check as JSON")
    check.set_defaults(run=run_check)


def _add_fetch(dsub: argparse._SubParsersAction) -> None:
    from evsmap.download import CACHE_ENV, MIRROR_ENV, RETRIES, format_size
    from evsmap.fetch import CONFIRM_BYTES
    from evsmap.samples import SAMPLES

    fetch = dsub.add_parser(
        "fetch", help="download the real sample data the tests and reproduce use",
        description="Download a sample's official archive (resuming an interrupted download), "
                    "extract only the files the tests and `evsmap reproduce` use, check them "
                    "against the catalogue and put them under --out (default: the data root: "
                    "$EVSMAP_DATA_ROOT, ../shared/data or ~/.cache/evsmap/data), written "
                    "completely or not at all, with a manifest (evsmap-sample.json). Without "
                    f"NAME, or with --list: the samples and whether each is present. "
                    f"Downloads of {format_size(CONFIRM_BYTES)} or more need --yes. "
                    f"${MIRROR_ENV}=URL fetches every archive from URL/<file name> instead "
                    "of its official site.")
    fetch.add_argument("name", nargs="?", choices=list(SAMPLES), metavar="NAME",
                       help=f"one of {', '.join(SAMPLES)}")
    fetch.add_argument("--list", action="store_true",
                       help="list the samples (source, size, present or not) and stop")
    fetch.add_argument("--out", type=Path, metavar="DIR",
                       help="data root to put the sample under (default: the data root)")
    fetch.add_argument("--yes", "-y", action="store_true",
                       help=f"go on with a download of {format_size(CONFIRM_BYTES)} or more "
                            "without asking")
    fetch.add_argument("--overwrite", action="store_true",
                       help="replace an existing sample (only once the new one is complete)")
    fetch.add_argument("--cache-dir", type=Path, metavar="DIR",
                       help=f"download folder (default: ${CACHE_ENV} or "
                            "~/.cache/evsmap/downloads)")
    fetch.add_argument("--keep-archive", action="store_true",
                       help="keep the downloaded archive in the download folder afterwards")
    fetch.add_argument("--retries", type=nonnegative_int, default=RETRIES, metavar="N",
                       help=f"times to resume a transfer that breaks off (default {RETRIES}); "
                            "a later call resumes too")
    fetch.add_argument("--json", action="store_true", help="with --list: print JSON")
    fetch.set_defaults(run=run_fetch)


def run_prepare(args: argparse.Namespace) -> int:
    from evsmap.interrupt import file_state, set_resume_hint

    name = args.dataset
    out = args.out if args.out is not None else DEFAULT_ROOT / name
    before = file_state(out)

    def hint() -> str:
        if file_state(out) != before:  # the signal came after the dataset was moved in
            return f"the dataset was complete before that: {out} is ready"
        return (f"{out} was not touched (a dataset is prepared in a staging folder and moved "
                f"into place at the end); run the same command again")

    set_resume_hint(hint)
    if name in GENERATED:
        return _run_generate(args, out)
    given = [f"--{k.replace('_', '-')}" for k in ("rooms", "frames_per_room", "size", "seed")
             if getattr(args, k) is not None]
    if given:
        raise EvsmapError(f"{', '.join(given)} applies to synthrooms only")
    if args.source is None:
        raise EvsmapError(f"{name} needs --from DIR ({_SOURCES[name]})")
    if not args.source.is_dir():
        state = "is a file, not a folder" if args.source.exists() else "no such folder"
        raise EvsmapError(f"--from {args.source}: {state} (give the {_SOURCES[name]})")
    options: dict = {"limit": args.limit, "overwrite": args.overwrite}
    if args.raw_depth:
        if name != "sunrgbd":
            raise EvsmapError("--raw-depth applies to sunrgbd only")
        options["raw_depth"] = True
    _claim_folder(args.out, out, overwrite=args.overwrite, source=args.source)
    prepare = get_preparer(name)
    t0 = time.perf_counter()
    manifest = prepare(args.source, out,
                       progress=lambda items: progress(items, desc=f"preparing {name}"),
                       **options)
    dt = time.perf_counter() - t0
    print(f"prepared {name} in {out} from {args.source} ({manifest['frames']} frames, "
          f"{dt:.1f} s)")
    official = manifest.get("official_counts", {})
    for split, count in manifest["splits"].items():
        note = f"  (official {official[split]})" if split in official else ""
        print(f"  {split:<6} {count:>6} frames{note}")
    if args.limit:
        print(f"  limited to the first {args.limit} frames of each split")
    return 0


def _claim_folder(given: Path | None, out: Path, *, overwrite: bool,
                  source: Path | None = None) -> None:
    """The output folder checked before any work (:func:`evsmap.cli.outputs.claim_outputs`):
    ``--out`` when ``given``, else the default ``out``, named as such."""
    from evsmap.cli.outputs import Output, claim_outputs

    option = "--out" if given is not None else "the output folder"
    if source is not None:
        src, dst = source.resolve(), out.resolve()
        if dst == src or dst in src.parents:
            raise EvsmapError(f"{option} {out}: would replace the --from folder; give another "
                              "--out")
    claim_outputs([Output(option, out, folder=True)], overwrite=overwrite)


def _run_generate(args: argparse.Namespace, out: Path) -> int:
    from evsmap.datasets import synthrooms as sr

    for option, value in (("--from", args.source), ("--limit", args.limit),
                          ("--raw-depth", args.raw_depth or None)):
        if value is not None:
            raise EvsmapError(f"{option} does not apply to {args.dataset} (it is rendered, not "
                              "converted; size it with --rooms and --frames-per-room)")
    try:
        size = sr.parse_size(args.size) if args.size is not None else sr.DEFAULT_SIZE
    except EvsmapError as exc:
        why = (f"height and width must each be in {sr.MIN_SIDE}..{sr.MAX_SIDE} pixels"
               if "must be in" in str(exc) else "must be HEIGHTxWIDTH in pixels, e.g. 240x320")
        raise EvsmapError(f"--size {args.size}: {why}") from None
    rooms = args.rooms if args.rooms is not None else sr.DEFAULT_ROOMS
    if rooms < sr.MIN_ROOMS:  # a one-line error before anything is rendered
        raise EvsmapError(f"--rooms {rooms}: {args.dataset} needs at least {sr.MIN_ROOMS} rooms "
                          f"(one each for train, val and test): pass --rooms {sr.MIN_ROOMS} or "
                          "more")
    sr.split_rooms(rooms)
    _claim_folder(args.out, out, overwrite=args.overwrite)
    frames = args.frames_per_room if args.frames_per_room is not None \
        else sr.DEFAULT_FRAMES_PER_ROOM
    seed = args.seed if args.seed is not None else sr.DEFAULT_SEED
    t0 = time.perf_counter()
    manifest = sr.prepare_synthrooms(
        out, rooms=rooms, frames_per_room=frames, size=size, seed=seed,
        overwrite=args.overwrite,
        progress=lambda items: progress(items, desc=f"rendering {args.dataset}"))
    dt = time.perf_counter() - t0
    print(f"prepared {args.dataset} in {out} ({manifest['frames']} frames: {rooms} rooms x "
          f"{frames} views, {size[0]}x{size[1]}, seed {seed}, {dt:.1f} s)")
    for split, count in manifest["splits"].items():
        scenes = ", ".join(f"{t} {n}" for t, n in manifest["split_scenes"][split].items() if n)
        print(f"  {split:<6} {count:>6} frames, {len(manifest['split_rooms'][split]):>3} rooms "
              f"({scenes})")
    return 0


def _describe(folder: Path) -> dict | None:
    from evsmap.datasets.common import MANIFEST, read_manifest
    from evsmap.registry import READERS

    if (folder / MANIFEST).is_file():
        try:
            record = read_manifest(folder) or {}  # the file is there: not None
        except DataFormatError as exc:
            return {"path": str(folder), "name": None, "error": str(exc)}
        name, splits = record.get("name"), record.get("splits")
        if not isinstance(name, str) or not (splits is None or isinstance(splits, dict)):
            return {"path": str(folder), "name": name if isinstance(name, str) else None,
                    "error": f"{folder / MANIFEST}: \"name\" must be a string and \"splits\" "
                             "an object (frames per split)"}
        return {"path": str(folder), "name": name, "splits": splits,
                "version": record.get("version"), "source": record.get("source")}
    for name in DATASETS:
        detect = READERS.get(name).extras.get("detect")
        if detect is not None and detect(folder):
            return {"path": str(folder), "name": name, "splits": None, "version": None,
                    "source": None, "note": "no manifest (not written by evsmap datasets prepare)"}
    return None


def run_list(args: argparse.Namespace) -> int:
    root: Path = args.root if args.root is not None else DEFAULT_ROOT
    where = "--root " if args.root is not None else ""
    if root.exists() and not root.is_dir():
        raise DataFormatError(f"{where}{root}: is a file, not a folder of datasets")
    if args.root is not None and not root.is_dir():
        raise DataFormatError(f"{where}{root}: no such folder")
    found = [d for d in (_describe(p) for p in sorted(root.iterdir()) if p.is_dir()) if d] \
        if root.is_dir() else []
    if args.json:
        print(json.dumps(found, indent=2))
        return 0
    if not found:
        print(_nothing_prepared(root))
        return 0
    width = max(len(d["path"]) for d in found)
    for d in found:
        if "error" in d:
            detail = d["error"]
        elif d["splits"]:
            detail = ", ".join(f"{k} {v}" for k, v in d["splits"].items())
            detail += f"  (from {d['source']})"
        else:
            detail = d.get("note", "")
        print(f"{d['name'] or '?':<11} {d['path']:<{width}}  {detail}")
    return 0


def _nothing_prepared(root: Path) -> str:
    """What ``datasets list`` says when nothing is prepared under ``root``: where it looked, the
    datasets evsmap reads and how each is prepared, and the data it reads where it lies."""
    state = "" if root.is_dir() else ": no such folder yet"
    lines = [f"no prepared datasets under {root} ({root.resolve()}{state})",
             "evsmap reads these once prepared (evsmap datasets prepare DATASET):"]
    width = max(len(n) for n in [*_SOURCES, *GENERATED])
    lines += [f"  {name:<{width}}  --from a {source}" for name, source in _SOURCES.items()]
    lines += [f"  {name:<{width}}  no --from: {what}" for name, what in GENERATED.items()]
    lines.append("and, where they lie: ScanNet (evsmap datasets check scannet), the real samples "
                 "(evsmap datasets fetch --list), any sequence folder or bag (evsmap info PATH)")
    return "\n".join(lines)


# -- check ----------------------------------------------------------------------------------------
def _scannet_root(given: Path | None) -> Path | None:
    if given is not None:
        return given
    from evsmap.paths import default_data_root

    for base in (default_data_root(), DEFAULT_ROOT):
        if base is not None and (Path(base) / "scannet").is_dir():
            return Path(base) / "scannet"
    return None


def run_check(args: argparse.Namespace) -> int:
    from evsmap.readers.scannet.check import OBTAIN, check_release

    root = _scannet_root(args.root)
    if root is None or not root.is_dir():
        where = f"--root {root}: no such folder" if args.root is not None else \
            "no scannet/ folder under the data root or datasets/"
        raise DataFormatError(f"{where}. {OBTAIN}")
    result = check_release(root, meshes=not args.no_meshes,
                           progress=lambda it: progress(list(it), desc="checking scenes"))
    problems = result.all_problems()
    if args.json:
        print(json.dumps(result.as_dict(), indent=2))
        return 1 if problems else 0
    frames = sum(s.frames or 0 for s in result.scenes)
    print(f"ScanNet at {root}: {len(result.scenes)} scenes, {frames:,} frames in their .sens "
          f"files, label table {'ok' if result.label_table else 'missing or unreadable'}")
    for split, listed in result.splits.items():
        print(f"  {split:<5} split: {result.split_present[split]} of its {listed} scenes present")
    with_2d = sum(s.label_images for s in result.scenes)
    lost = sum(s.invalid_poses or 0 for s in result.scenes)
    print(f"  {with_2d} scenes with 2D label images; {lost:,} frames with invalid (-inf) poses "
          f"(skipped with --skip-bad)")
    for line in problems:
        print(f"problem: {line}")
    print("no problems found" if not problems else f"{len(problems)} problem(s)")
    return 1 if problems else 0


# -- fetch ----------------------------------------------------------------------------------------
def _ask(message: str) -> bool:
    sys.stderr.write(f"{message} [y/N] ")
    sys.stderr.flush()
    try:
        answer = input()
    except EOFError:
        return False
    return answer.strip().lower() in ("y", "yes")


def _say(message: str) -> None:
    print(message, flush=True)


def run_fetch(args: argparse.Namespace) -> int:
    from evsmap.fetch import fetch_sample, summarize
    from evsmap.paths import default_data_root, shared_data_dir

    if args.list or args.name is None:
        return _list_samples(args)
    if args.json:
        raise EvsmapError("--json applies to the list (--list or no NAME)")
    from evsmap.samples import SAMPLES

    root = args.out if args.out is not None else default_data_root()
    _check_root(args, root)
    sample = SAMPLES[args.name]
    target = root / sample.folder
    shared = shared_data_dir()
    if shared is not None and root.resolve() == shared.resolve():
        if target.exists():
            raise EvsmapError(f"{target}: {args.name} is already in the shared data folder, "
                              "which is read-only for evsmap: nothing to fetch (pass --out DIR "
                              "to fetch another copy elsewhere)")
        if args.overwrite:
            raise EvsmapError(f"{root}: the shared data folder is read-only for evsmap; pass "
                              "--out DIR to fetch elsewhere")
    # every output checked before any download: the sample, and the download folder
    from evsmap.cli.outputs import Output, check_writable, claim_outputs

    option = "--out" if args.out is not None else "the data root"
    claim_outputs([Output(option, target, folder=not sample.single_file)],
                  overwrite=args.overwrite)
    if args.cache_dir is not None:
        if args.cache_dir.exists() and not args.cache_dir.is_dir():
            raise EvsmapError(f"--cache-dir {args.cache_dir}: is a file, not a folder")
        if not args.cache_dir.exists():
            check_writable(Output("--cache-dir", args.cache_dir, folder=True))
    interactive = sys.stdin.isatty() and sys.stderr.isatty()
    from evsmap.interrupt import set_resume_hint

    set_resume_hint("a partial download is kept (NAME.part in the download cache) and is "
                    "resumed where it stopped: run the same command again")
    t0 = time.perf_counter()
    manifest = fetch_sample(args.name, root, overwrite=args.overwrite, yes=args.yes,
                            cache_dir=args.cache_dir, retries=args.retries,
                            keep_archive=args.keep_archive,
                            confirm=_ask if interactive else None, log=_say)
    print(f"fetched {args.name} into {target} ({summarize(manifest)}, "
          f"{time.perf_counter() - t0:.1f} s)")
    return 0


def _check_root(args: argparse.Namespace, root: Path) -> None:
    """A data root that is a file: one line naming it (and the option that gave it)."""
    if root.exists() and not root.is_dir():
        if args.out is not None:
            raise EvsmapError(f"--out {root}: is a file, not a folder (give the data root "
                              "folder the samples go under)")
        raise EvsmapError(f"{root}: the data root is a file, not a folder (set "
                          "$EVSMAP_DATA_ROOT to a folder, or pass --out DIR)")


def _sample_rows(root: Path) -> list[dict]:
    from evsmap.fetch import read_sample_manifest
    from evsmap.samples import SAMPLES

    rows = []
    for sample in SAMPLES.values():
        path = root / sample.folder
        manifest = read_sample_manifest(sample, root) if path.exists() else None
        date = manifest.get("date") if manifest else None
        rows.append({
            "name": sample.name, "path": str(path), "present": path.exists(),
            "fetched": date if isinstance(date, str) else None,
            "size": sample.size_text(), "description": sample.description,
            "sources": [{"url": s.url, "file": s.filename, "size": s.size, "sha256": s.sha256}
                        for s in sample.sources],
            "checks": sample.checks,
        })
    return rows


def _list_samples(args: argparse.Namespace) -> int:
    from evsmap.paths import default_data_root

    root = args.out if args.out is not None else default_data_root()
    _check_root(args, root)
    rows = _sample_rows(root)
    if args.json:
        print(json.dumps({"root": str(root), "samples": rows}, indent=2))
        return 0
    print(f"samples under {root}  (evsmap datasets fetch NAME)")
    width = max(len(r["name"]) for r in rows)
    for r in rows:
        if r["present"]:
            present = f"yes (fetched {r['fetched'][:10]})" if r["fetched"] else "yes"
        else:
            present = "no"
        more = len(r["sources"]) - 1
        source = r["sources"][0]["url"] + (f" (+{more} more)" if more else "")
        print(f"{r['name']:<{width}}  {present:<22}  {r['size']:<22}  {source}")
    return 0
