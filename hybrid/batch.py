"""Batch runs: every video in a folder, each in its own work directory, failures isolated.

Writes out/<video name>/ per video (see hybrid.pipeline), out/<video name>/error.txt when a
video fails (never into a folder that holds another video's run), and out/summary.csv (one row
per video by its resolved path, rewritten atomically after each video; a batch keeps the rows
earlier ones left, so that videos it has not reached yet, and those of other folders batched
into the same out, keep theirs). A video whose report exists is skipped; an interrupted one
resumes at its first missing stage. With several workers each video runs in a process of its
own, so that one that dies fails only its own video.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import os
import traceback
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from hybrid import LOG_FORMAT
from hybrid import workdir as W
from hybrid.pipeline import Models, RunConfig, run_video
from hybrid.types import InputError
from learned.frames import VIDEO_SUFFIXES

SUMMARY = "summary.csv"
FIELDS = ("video", "status", "frames", "seconds_of_video", "segments", "mean_learned",
          "mean_geometric", "agreement", "deficient_segments", "not_assessable", "warnings",
          "error")


@dataclass(frozen=True)
class BatchResult:
    summary: Path
    """summary.csv: this batch's videos and those earlier batches into the same out left."""
    rows: list[dict]
    """This batch's videos' rows, in the order of list_videos."""


def list_videos(folder: Path) -> list[Path]:
    """The video files of a folder (not its subfolders, nor folders or hidden files with a
    video's suffix, such as the ._ files macOS leaves), as absolute paths."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"video folder not found: {folder}")
    videos = sorted(p.absolute() for p in folder.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES
                    and not p.name.startswith(".") and not p.is_dir())
    if not videos:
        raise InputError(f"no videos ({', '.join(sorted(VIDEO_SUFFIXES))}) in {folder}")
    return videos


def run_batch(folder: Path, out: Path, config: RunConfig | None = None, workers: int = 1,
              progress: bool = True, device: torch.device | str = "cpu") -> BatchResult:
    """Run every video, the networks on `device`."""
    config = config or RunConfig()
    videos = list_videos(folder)
    W.check_not_input(out, folder)
    # Loaded before anything is written, so that networks this configuration cannot run are
    # refused up front.
    models = Models.load(config, device if workers == 1 else "cpu")
    out = W.make_folder(out)
    rows = _earlier_rows(out)
    bar = tqdm(total=len(videos), desc="videos", unit="video", disable=not progress)
    if workers == 1:
        for video in videos:
            rows[_key(video)] = _run_one(video, out / video.name, config, models)
            _write_summary(out, videos, rows)
            bar.update(1)
    else:
        del models  # each worker loads its own
        threads = max(1, (os.cpu_count() or 1) // workers)
        with ThreadPoolExecutor(workers) as pool:
            futures = {pool.submit(_run_in_process, v, out / v.name, config, device, threads): v
                       for v in videos}
            try:
                for future in as_completed(futures):
                    rows[_key(futures[future])] = future.result()
                    _write_summary(out, videos, rows)
                    bar.update(1)
            except BaseException:  # e.g. Ctrl-C: start no more videos (those running end
                # with the signal or run to their end)
                pool.shutdown(wait=False, cancel_futures=True)
                raise
    bar.close()
    return BatchResult(out / SUMMARY, [rows[_key(video)] for video in videos])


def _run_in_process(video: Path, work: Path, config: RunConfig, device: torch.device | str,
                    threads: int) -> dict:
    """`_run_one` in a process of its own, so that a process that dies (e.g. killed for its
    memory) fails its own video only: the row says so, and work/error.txt."""
    try:
        return in_own_process(_run_one, video, work, config, None, device, threads=threads)
    except Exception as err:  # the process died, or could not start
        message = (f"the process running this video died ({err}); it may have run out of "
                   f"memory: run it alone, or with fewer --workers"
                   if isinstance(err, BrokenProcessPool) else
                   f"no process could run this video ({type(err).__name__}: {err})")
        _record_failure(video, work, message)
        return {"video": _key(video), "status": "failed", "error": message}


def in_own_process(function: Callable, *args, threads: int = 1):
    """function(*args) in a fresh spawned process (not forked: a forked one cannot use CUDA)
    with `threads` torch threads and this process's logging level; BrokenProcessPool if that
    process dies."""
    with ProcessPoolExecutor(1, mp_context=get_context("spawn"), initializer=_start_worker,
                             initargs=(threads, logging.getLogger().level)) as pool:
        return pool.submit(function, *args).result()


def _start_worker(threads: int, log_level: int) -> None:
    """A spawned worker process: its share of the CPU threads and the parent's logging."""
    torch.set_num_threads(threads)
    logging.basicConfig(level=log_level, format=LOG_FORMAT)


def _run_one(video: Path, work: Path, config: RunConfig, models: Models | None,
             device: torch.device | str = "cpu") -> dict:
    """One video (its own Models loaded on `device` if none are given); any failure becomes
    a row with its error (and work/error.txt)."""
    try:
        done_before = (work / W.REPORT).is_file()
        models = models or Models.load(config, device)
        result = run_video(video, work, config, models, progress=False)
        (work / W.ERROR).unlink(missing_ok=True)
        row = _summarise(work)
        row.update(status="done before" if done_before else "done",
                   warnings="; ".join(result["warnings"]))
    except Exception as err:  # isolate every failure, expected or not, to its video
        _record_failure(video, work, str(err) if isinstance(err, InputError) else
                        traceback.format_exc())
        row = {"status": "failed", "error": str(err).splitlines()[0] if str(err) else
               type(err).__name__}
    row["video"] = _key(video)
    return row


def _record_failure(video: Path, work: Path, message: str) -> None:
    """work/error.txt, unless work is a file or holds another input's run (the row says why
    the video failed either way)."""
    if work.exists() and not work.is_dir():
        return
    config = work / W.CONFIG
    if config.is_file():
        try:
            source = json.loads(config.read_text())["source"]["path"]
        except (OSError, ValueError, KeyError, TypeError):  # not a run this c2d2 wrote
            return
        if source != _key(video):
            return
    try:
        W.make_folder(work)
        W.write_text(work / W.ERROR, message + "\n")
    except (InputError, OSError) as err:  # e.g. the disk is full: the row still says it
        logging.getLogger(__name__).warning("%s: %s not written: %s", work, W.ERROR, err)


def _summarise(work: Path) -> dict:
    table = json.loads((work / W.COVERAGE_JSON).read_text())
    ingest = json.loads((work / W.INGEST).read_text())
    segments = table["segments"]

    def mean(key: str) -> float | str:
        values = [s[key] for s in segments if s[key] is not None]
        return round(float(np.mean(values)), 4) if values else ""

    return {"frames": ingest["frames"],
            "seconds_of_video": round(ingest["frames"] / ingest["fps"], 2),
            "segments": len(segments), "mean_learned": mean("learned"),
            "mean_geometric": mean("geometric"),
            "agreement": "" if table["agreement"] is None else round(table["agreement"], 4),
            "deficient_segments": sum(s["deficient"] for s in segments),
            "not_assessable": sum(not s["assessable"] for s in segments)}


def _earlier_rows(out: Path) -> dict[str, dict]:
    """The rows earlier batches into `out` left, by video, so that a rerun stopped before it
    reaches a video does not list it as pending, and another folder's videos keep theirs."""
    path = out / SUMMARY
    if not path.is_file():
        return {}
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        if not {"video", "status"} <= set(reader.fieldnames or ()):
            raise InputError(f"{path} is not a summary written by c2d2 batch (no video and "
                             f"status columns); choose another --out")
        rows = [row | {"video": _key(Path(row["video"]))} for row in reader
                if row["status"] != "pending"]
    return {row["video"]: row for row in rows}


def _key(video: Path) -> str:
    """A video's row: its path resolved (as its run's config.json records it; earlier batches
    wrote paths as given, read here from the working directory)."""
    return str(video.resolve())


def _write_summary(out: Path, videos: list[Path], rows: dict[str, dict]) -> None:
    """This batch's videos (pending where not yet run) and the other rows, by video."""
    rows = {_key(v): {"video": _key(v), "status": "pending"} for v in videos} | rows
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=FIELDS)
    writer.writeheader()
    for video in sorted(rows):
        writer.writerow({k: rows[video].get(k, "") for k in FIELDS})
    W.write_text(out / SUMMARY, text.getvalue())
