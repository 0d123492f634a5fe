"""The "real time on this machine" section after Table IV (``evsmap reproduce --precision
int8`` with Table IV; records ``extra/realtime/...`` from :mod:`evsmap.runner.realtime`): EVSMap
end to end with FEAGNet int8, the faithful path beside its named variants."""

from __future__ import annotations

from collections.abc import Iterable

from evsmap.runner.records import CellRecord

PREFIX = "extra/realtime/"
SECTION = "Real time on this machine: the faithful path and its variants"
PATHS = (("network", "faithful (network resizes, top-k of every pixel)"),
         ("fused", "fused (same labels and map)"),
         ("stride", "stride (variant: top-k at the output stride)"))
GOALS = {"feagnet-v2": 14.4, "feagnet-v1": 30.0}
"""The rates asked of this machine (issue 40): the paper's EVSMap on a Jetson AGX Xavier maps at
14.4 Hz with FEAGNet-V2; FEAGNet-V1 at twice FEAGNet-V2's frame rate."""


def realtime_records(records: Iterable[CellRecord]) -> list[CellRecord]:
    return sorted((r for r in records if r.key.startswith(PREFIX)), key=lambda r: r.key)


def realtime_markdown(records: Iterable[CellRecord]) -> list[str]:
    """The section (empty without realtime records)."""
    recs = realtime_records(records)
    if not recs:
        return []
    out = [f"## {SECTION}", "",
           "Measured in this run, not the paper's: `evsmap map`'s pipelined loop (reading, "
           "segmentation and update of consecutive frames overlapped) with EVSMap on the "
           "synthetic room, frames / wall time with reading included, each post-processing "
           "path in alternating runs. `fused` computes the same labels and the same EVSMap map "
           "as the faithful path; `stride` is a named variant whose labels move along class "
           "boundaries (its accuracy cost on trained weights: docs/realtime.md). Goal: the "
           "rate asked of this machine (issue 40).", "",
           "| Network | " + " | ".join(f"{label} (Hz)" for _, label in PATHS)
           + " | Goal (Hz) | Instruction set, int8 scheme |",
           "|---|" + "---:|" * len(PATHS) + "---:|---|"]
    for rec in recs:
        network = rec.inputs.get("segmenter", "?")
        if rec.status != "ok":
            why = rec.error or rec.reason or rec.status
            out.append(f"| {network} | {rec.status}: {why} |" + " |" * (len(PATHS) + 1))
            continue
        d = rec.details
        rates = " | ".join(_hz(rec.values.get(f"wall_hz_{post}")) for post, _ in PATHS)
        goal = GOALS.get(network)
        out.append(f"| {network} | {rates} | {'-' if goal is None else f'{goal:g}'} | "
                   f"{d.get('instruction_set', '-')}, {d.get('int8_scheme', '-')} "
                   f"({d.get('int8_scheme_chosen_by', '-')}) |")
    return out + [""]


def _hz(value) -> str:
    return "-" if value is None or value != value else f"{value:.2f}"
