"""Batch runs: every video in a folder, each in its own work directory, failures isolated.

Writes out/<video name>/ per video (see hybrid.pipeline), out/<video name>/error.txt when a
video fails, and out/summary.csv (one row per video, rewritten atomically after each video;
a rerun starts from the rows an earlier one left, so videos it has not reached yet keep theirs).
A video whose report exists is skipped; an interrupted one resumes at its first missing stage.
With several workers each video runs in a process of its own, so that one that dies fails
only its own video.
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


def list_videos(folder: Path) -> list[Path]:
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"video folder not found: {folder}")
    videos = sorted(p for p in folder.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES)
    if not videos:
        raise InputError(f"no videos ({', '.join(sorted(VIDEO_SUFFIXES))}) in {folder}")
    return videos


def run_batch(folder: Path, out: Path, config: RunConfig | None = None, workers: int = 1,
              progress: bool = True, device: torch.device | str = "cpu") -> Path:
    """Run every video, the networks on `device`; returns the summary CSV's path."""
    config = config or RunConfig()
    videos = list_videos(folder)
    # Loaded before any video starts, so that networks this configuration cannot run are
    # refused up front.
    models = Models.load(config, device if workers == 1 else "cpu")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = _earlier_rows(out, videos)
    bar = tqdm(total=len(videos), desc="videos", unit="video", disable=not progress)
    if workers == 1:
        for video in videos:
            rows[video.name] = _run_one(video, out / video.name, config, models)
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
                    rows[futures[future].name] = future.result()
                    _write_summary(out, videos, rows)
                    bar.update(1)
            except BaseException:  # e.g. Ctrl-C: start no more videos (those running end
                # with the signal or run to their end)
                pool.shutdown(wait=False, cancel_futures=True)
                raise
    bar.close()
    return out / SUMMARY


def _run_in_process(video: Path, work: Path, config: RunConfig, device: torch.device | str,
                    threads: int) -> dict:
    """`_run_one` in a process of its own, so that a process that dies (e.g. killed for its
    memory) fails its own video only: the row says so, and work/error.txt."""
    try:
        return in_own_process(_run_one, video, work, config, None, device, threads=threads)
    except Exception as err:  # the process died, or could not start
        work.mkdir(parents=True, exist_ok=True)
        message = (f"the process running this video died ({err}); it may have run out of "
                   f"memory: run it alone, or with fewer --workers"
                   if isinstance(err, BrokenProcessPool) else
                   f"no process could run this video ({type(err).__name__}: {err})")
        W.write_text(work / W.ERROR, message + "\n")
        return {"video": str(video), "status": "failed", "error": message}


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
    error_file = work / W.ERROR
    try:
        done_before = (work / W.REPORT).is_file()
        models = models or Models.load(config, device)
        result = run_video(video, work, config, models, progress=False)
        if error_file.is_file():
            error_file.unlink()
        row = _summarise(work)
        row.update(status="done before" if done_before else "done",
                   warnings="; ".join(result["warnings"]))
    except Exception as err:  # isolate every failure, expected or not, to its video
        work.mkdir(parents=True, exist_ok=True)
        message = str(err) if isinstance(err, InputError) else traceback.format_exc()
        W.write_text(error_file, message + "\n")
        row = {"status": "failed", "error": str(err).splitlines()[0] if str(err) else
               type(err).__name__}
    row["video"] = str(video)
    return row


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


def _earlier_rows(out: Path, videos: list[Path]) -> dict[str, dict]:
    """The rows an earlier batch into `out` left for these videos, so that a rerun stopped
    before it reaches them does not list them as pending."""
    path = out / SUMMARY
    if not path.is_file():
        return {}
    names = {str(video): video.name for video in videos}
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        if not {"video", "status"} <= set(reader.fieldnames or ()):
            raise InputError(f"{path} is not a summary written by c2d2 batch (no video and "
                             f"status columns); choose another --out")
        return {names[row["video"]]: row for row in reader
                if row["video"] in names and row["status"] != "pending"}


def _write_summary(out: Path, videos: list[Path], rows: dict[str, dict]) -> None:
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=FIELDS)
    writer.writeheader()
    for video in videos:
        row = rows.get(video.name, {"video": str(video), "status": "pending"})
        writer.writerow({k: row.get(k, "") for k in FIELDS})
    W.write_text(out / SUMMARY, text.getvalue())
