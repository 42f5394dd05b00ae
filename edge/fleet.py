"""`edge-depth fleet replay|compare|evaluate SOURCES… --out DIR`: a fleet's recordings on Ray.

SOURCES are recordings (.mcap), folders of them (searched recursively) or ROS 2 bag
directories (a folder with metadata.yaml is one recording). Each recording is one task on a
worker: one Ray actor per slot, holding the engine loaded once, with `threads` engine threads
and `num_cpus = threads`, so workers × threads fit the cluster's cores. Ray runs locally by
default (no cluster needed) or joins one with `--address`.

- `replay`: DIR/NAME.mcap, the single-file `replay`'s output for that recording;
- `compare`: the same replay, then the single-file `compare` against the golden replay
  BASE/NAME.mcap (`--base`, e.g. an earlier `fleet replay`'s DIR); a regression exits 1;
- `evaluate`: the replay without an output file: frames, LiDAR pairing, EPE / bad-3 against
  the recording's ground truth.

Nothing lost, nothing repeated: beside each output a result record DIR/NAME.result.json
holds the outcome and a fingerprint of everything that made it (the input's size and mtime,
the bundle's bytes, the options, the golden replay); a rerun skips a recording whose
fingerprint is unchanged, failed ones included (an unreadable file fails the same way
again). A recording that cannot be read fails alone with its reason; a worker process that
dies is restarted by Ray and its task retried; one lost for good is reported and left
without a record, so the next run tries it again. Outputs are written under a temporary
name and renamed, so DIR never holds a half-written replay.

A recording read past damage (a damaged chunk, a cut-off end) is `damaged`, not `ok`: its
outputs are kept (the replay of what could be read) and its row says what the input lost.

At the end: a table per recording in the terminal and as DIR/summary.md + summary.json.
Exit status 1 when a recording failed or a `compare` found a regression; else, with
`strict`, DAMAGED_EXIT when a recording is damaged; else 0.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from edge_depth.calibration.atomic import atomic_write
from edge_depth.errors import ConfigError
from edge_depth.runtime.options import EngineOptions

log = logging.getLogger(__name__)

FLEET_EXTRA_HINT = "pip install 'edge-depth[fleet]'"
COMMANDS = ("replay", "compare", "evaluate")
RECORD_SUFFIX = ".result.json"
DAMAGED_EXIT = 3  # --strict: a damaged recording, and nothing worse (failed: 1, usage: 2)
KEPT = ("ok", "damaged")  # the statuses whose outputs are kept


@dataclass(frozen=True)
class Recording:
    """One input: a .mcap file or a ROS 2 bag directory, and the stem of its outputs."""

    path: Path
    name: str


@dataclass(frozen=True)
class FleetJob:
    """What every task of one `fleet` invocation does. `engine`: each worker's engine;
    `replay`: replay_recording's other arguments (calib, topics, profile)."""

    command: str
    out_dir: Path
    engine: EngineOptions = field(default_factory=EngineOptions)
    replay: dict = field(default_factory=dict)
    base_dir: Path | None = None  # compare: the golden replays
    tolerance_px: float = 0.25
    max_share: float = 0.01


def _is_bag(path: Path) -> bool:
    return path.is_dir() and (path / "metadata.yaml").is_file()


def find_recordings(sources: list[Path]) -> list[Recording]:
    """Every recording under SOURCES, in a stable order, each with a unique output stem
    (the file's stem; where two share one, their paths below the source joined by '__')."""
    found: list[tuple[Path, Path]] = []  # (recording, the source it was found under)
    for source in map(Path, sources):
        if _is_bag(source) or source.is_file():
            found.append((source, source.parent))
        elif source.is_dir():
            bags = sorted(p.parent for p in source.rglob("metadata.yaml"))
            found += [(bag, source) for bag in bags]
            found += [(p, source) for p in sorted(source.rglob("*.mcap"))
                      if not any(bag in p.parents for bag in bags)]
        else:
            raise ConfigError("SOURCES", "recordings, folders of them or ROS 2 bag "
                              "directories", str(source))
    if not found:
        raise ConfigError("SOURCES", "at least one recording (.mcap or a ROS 2 bag)",
                          [str(s) for s in sources])
    stems = [p.stem if p.suffix == ".mcap" else p.name for p, _ in found]
    recordings = []
    for (path, root), stem in zip(found, stems, strict=True):
        if stems.count(stem) > 1:
            stem = "__".join(path.relative_to(root).with_suffix("").parts)
        recordings.append(Recording(path.resolve(), stem))
    return recordings


def _file_identity(path: Path) -> list:
    """Size and mtime of a file, or of each file of a bag directory."""
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    return [[p.name, p.stat().st_size, p.stat().st_mtime_ns] for p in files]


def _digest_files(path: Path) -> str:
    """sha256 over a file's or a folder's bytes (the bundle: a few MB)."""
    h = hashlib.sha256()
    for p in sorted(q for q in path.rglob("*") if q.is_file()) if path.is_dir() else [path]:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def job_digest(job: FleetJob) -> str:
    """What every recording's outcome shares: the command, the bundle's bytes, the
    calibration's, the options and the compare limits (computed once per invocation)."""
    from edge_depth.runtime.engine import DEFAULT_BUNDLE

    replay = dict(job.replay)
    if replay.get("calib"):
        replay["calib"] = _digest_files(Path(replay["calib"]))
    text = json.dumps(dict(command=job.command,
                           bundle=_digest_files(Path(job.engine.bundle or DEFAULT_BUNDLE)),
                           engine=asdict(job.engine), replay=replay, tolerance=job.tolerance_px,
                           max_share=job.max_share), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def fingerprint(recording: Recording, job: FleetJob, shared: str) -> str:
    """What made a recording's outcome — its input, its golden replay and the job's
    `shared` digest: if it is unchanged, so is the outcome."""
    golden = None
    if job.base_dir is not None:
        base = job.base_dir / f"{recording.name}.mcap"
        golden = _file_identity(base) if base.exists() else "missing"
    text = json.dumps(dict(input=_file_identity(recording.path), golden=golden, job=shared),
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def record_path(job: FleetJob, recording: Recording) -> Path:
    return job.out_dir / f"{recording.name}{RECORD_SUFFIX}"


def previous_record(job: FleetJob, recording: Recording, print_: str) -> dict | None:
    """The record of an earlier run with this fingerprint whose output is still there."""
    path = record_path(job, recording)
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("fingerprint") != print_:
        return None
    if record.get("status") in KEPT and not all(Path(f).exists()
                                                for f in record.get("files", [])):
        return None
    if record.get("status") in KEPT and "lost" not in record:
        return None  # written before records said what the input lost: its "ok" may hide it
    return record


def run_one(engine, recording: Recording, job: FleetJob) -> dict:
    """One task: the replay (and compare) of one recording with a loaded engine. Never
    raises: a recording that fails is a record with its reason."""
    from edge_depth.commands import open_recording, replay_recording

    record: dict[str, Any] = dict(name=recording.name, input=str(recording.path),
                                  command=job.command, status="ok", reason="")
    out = None if job.command == "evaluate" else job.out_dir / f"{recording.name}.mcap"
    partial = None if out is None else out.with_name(f".{out.stem}.partial.mcap")
    started = time.monotonic()
    try:
        options = dict(job.replay)
        profile = options.pop("profile", "foxglove")
        done = replay_recording(engine, open_recording(recording.path, partial, **options),
                                partial, profile)
        record.update(done.record())
        if (failure := done.failure()) is not None:
            raise ValueError(failure)
        if out is not None and partial is not None:
            os.replace(partial, out)
            record["files"] = [str(out)]
        if job.command == "compare" and out is not None:
            record.update(_compare(out, job, recording))
        if done.source.stats.lost:  # read past damage: kept, and said what it lost
            record.update(status="damaged", reason=_lost_note(done.source.stats.lost))
    except Exception as exc:  # noqa: BLE001 - one recording's failure never stops the rest
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        record.update(status="failed", reason=reason, files=[])
    finally:
        if partial is not None and partial.exists():
            partial.unlink()
    record["wall_s"] = round(time.monotonic() - started, 3)
    return record


def _lost_note(lost: list[str], shown: int = 2) -> str:
    """What a damaged recording lost, for the table's note: the first `shown` of it."""
    more = f"; and {len(lost) - shown} more" if len(lost) > shown else ""
    return "input " + "; ".join(lost[:shown]) + more


def _compare(out: Path, job: FleetJob, recording: Recording) -> dict:
    from edge_depth.compare import compare

    if job.base_dir is None:
        raise ValueError("compare needs --base, the folder of golden replays")
    base = job.base_dir / f"{recording.name}.mcap"
    if not base.exists():
        raise ValueError(f"no golden replay {base} to compare with")
    result = compare(base, out, job.tolerance_px, job.max_share)
    return dict(verdict="REGRESSION" if result["regressions"] else "OK",
                regressions=result["regressions"], mean_abs_px=result["mean_abs_px"],
                beyond_share=result["beyond_share"])


def _actor_class(ray):
    @ray.remote(max_restarts=2, max_task_retries=2)
    class FleetWorker:
        """One slot: the engine loaded once, then one recording per call."""

        def __init__(self, options: EngineOptions) -> None:
            from threadpoolctl import threadpool_limits

            from edge_depth.runtime.engine import Engine

            threadpool_limits(1)  # numpy's BLAS: the engine's threads are the slot's
            self.engine = Engine(options=options)

        def run(self, recording: Recording, job: FleetJob) -> dict:
            return run_one(self.engine, recording, job)

    return FleetWorker


def _progress(total: int):
    """A progress bar over recordings (tqdm, from the fleet extra), or a line per recording."""
    try:
        from tqdm import tqdm
    except ModuleNotFoundError:
        return None
    return tqdm(total=total, unit="rec", file=sys.stderr, dynamic_ncols=True)


def _init_ray(ray, address: str | None, workers: int | None, threads: int) -> None:
    options = dict(include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING,
                   configure_logging=False)
    if address is None:  # local: one CPU per core, a small object store (records are small)
        ray.init(num_cpus=max(os.cpu_count() or 1, (workers or 1) * threads),
                 object_store_memory=100 * 2**20, **options)
    else:
        ray.init(address=address, **options)


def run_tasks(recordings: list[Recording], job: FleetJob, address: str | None,
              workers: int | None) -> list[dict]:
    """Every recording on the workers, as they come free; records in completion order."""
    import ray

    owned = not ray.is_initialized()  # a caller's session (a notebook, a scheduler) is used
    if owned:
        _init_ray(ray, address, workers, job.engine.threads)
    try:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        threads = job.engine.threads
        slots = min(len(recordings), workers or max(1, cpus // threads))
        worker = _actor_class(ray).options(num_cpus=threads)
        idle = [worker.remote(job.engine) for _ in range(slots)]
        todo, records = list(recordings), []
        pending: dict[Any, tuple[Any, Recording]] = {}
        bar, frames = _progress(len(recordings)), 0
        while todo or pending:
            while idle and todo:
                actor, recording = idle.pop(), todo.pop(0)
                pending[actor.run.remote(recording, job)] = (actor, recording)
            (ref,), _ = ray.wait(list(pending), num_returns=1)
            actor, recording = pending.pop(ref)
            try:
                record = ray.get(ref)
                idle.append(actor)
            except ray.exceptions.RayError as exc:  # a worker lost for good: not recorded
                record = dict(name=recording.name, input=str(recording.path), status="lost",
                              reason=f"worker lost: {type(exc).__name__}", files=[])
                idle.append(worker.remote(job.engine))
            records.append(record)
            frames += record.get("frames") or 0
            line = _progress_line(record)
            if bar is None:
                print(line, file=sys.stderr, flush=True)
            else:
                bar.set_postfix(frames=frames)
                bar.write(line, file=sys.stderr)
                bar.update(1)
        if bar is not None:
            bar.close()
        return records
    finally:
        if owned:
            ray.shutdown()


def _progress_line(record: dict) -> str:
    if record["status"] not in KEPT:
        return f"{record['name']}: {record['status']} ({record['reason']})"
    ms = record.get("ms_per_frame")
    return (f"{record['name']}: {record['frames']} frames"
            + (f", {ms:.0f} ms/frame" if ms is not None else "")
            + (f", {record['verdict']}" if "verdict" in record else "")
            + (f", damaged ({record['reason']})" if record["status"] == "damaged" else ""))


def fleet_command(job: FleetJob, sources: list[Path], address: str | None = None,
                  workers: int | None = None, strict: bool = False) -> int:
    """The whole fleet: find, skip what is unchanged, run the rest, write the summary.
    `strict`: a damaged recording exits DAMAGED_EXIT (where none failed or regressed)."""
    try:
        import ray  # noqa: F401 - only to say how to install it
    except ModuleNotFoundError:
        print(f"edge-depth fleet: needs Ray, from the fleet extra: {FLEET_EXTRA_HINT}",
              file=sys.stderr)
        return 1
    from edge_depth.config import check_output_path

    recordings = find_recordings(sources)
    check_output_path(job.out_dir, "--out", folder=True)
    shared = job_digest(job)
    prints = {r.name: fingerprint(r, job, shared) for r in recordings}
    earlier = {r.name: previous_record(job, r, prints[r.name]) for r in recordings}
    todo = [r for r in recordings if earlier[r.name] is None]
    print(f"edge-depth fleet {job.command}: {len(recordings)} recordings, "
          f"{len(recordings) - len(todo)} unchanged since their last run (skipped), "
          f"{len(todo)} to run", flush=True)
    started = time.monotonic()
    fresh = run_tasks(todo, job, address, workers) if todo else []
    wall_s = time.monotonic() - started
    for record in fresh:
        record["fingerprint"] = prints[record["name"]]
        if record["status"] != "lost":
            with atomic_write(record_path(job, Recording(Path(record["input"]),
                                                          record["name"]))) as tmp:
                tmp.write_text(json.dumps(record, indent=2, default=str))
    by_name = {r["name"]: dict(r, ran=True) for r in fresh}
    rows = [by_name.get(r.name) or dict(earlier[r.name] or {}, ran=False) for r in recordings]
    summary = summarise_fleet(job, rows, wall_s, sum(r.get("frames") or 0 for r in fresh))
    print(summary["markdown"])
    (job.out_dir / "summary.md").write_text(summary["markdown"] + "\n")
    (job.out_dir / "summary.json").write_text(json.dumps(
        {k: v for k, v in summary.items() if k != "markdown"}, indent=2, default=str))
    if summary["failed"] or summary["regressions"]:
        return 1
    return DAMAGED_EXIT if strict and summary["damaged"] else 0


def _cell(value, fmt: str = "{}") -> str:
    return "–" if value is None else fmt.format(value)


def summarise_fleet(job: FleetJob, rows: list[dict], wall_s: float, frames_run: int) -> dict:
    """The table and its totals, as markdown and as data."""
    lines = ["| recording | status | frames | with LiDAR | ms/frame | EPE px | bad-3 % | "
             "verdict | note |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        note = "; ".join(filter(None, [r.get("reason"), *(r.get("regressions") or [])])) or (
            "unchanged: skipped" if not r["ran"] else "")
        lines.append(
            f"| {r['name']} | {r['status']} | {_cell(r.get('frames'))} | "
            f"{_cell(r.get('frames_with_lidar'))} | {_cell(r.get('ms_per_frame'), '{:.1f}')} | "
            f"{_cell(r.get('epe'), '{:.3f}')} | {_cell(r.get('bad3'), '{:.2f}')} | "
            f"{r.get('verdict', '–')} | {note} |")
    failed = [r["name"] for r in rows if r["status"] not in KEPT]
    damaged = [r["name"] for r in rows if r["status"] == "damaged"]
    regressions = [r["name"] for r in rows if r.get("verdict") == "REGRESSION"]
    ran = sum(r["ran"] for r in rows)
    rate = frames_run / wall_s if ran and wall_s > 0 else None
    lines.append("")
    lines.append(f"{len(rows)} recordings: {ran} run, {len(rows) - ran} skipped (unchanged), "
                 f"{len(failed)} failed" + (f" ({', '.join(failed)})" if failed else "")
                 + f", {len(damaged)} damaged" + (f" ({', '.join(damaged)})" if damaged else "")
                 + (f", {len(regressions)} regressed"
                    + (f" ({', '.join(regressions)})" if regressions else "")
                    if job.command == "compare" else "")
                 + f"; {frames_run} frames in {wall_s:.1f} s"
                 + (f" ({rate:.1f} frames/s)" if rate else ""))
    return dict(command=job.command, job=asdict(job), recordings=rows, failed=failed,
                damaged=damaged, regressions=regressions, wall_s=wall_s, frames_run=frames_run,
                frames_per_s=rate, markdown="\n".join(lines))
