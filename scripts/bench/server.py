#!/usr/bin/env python3
"""Benchmark the XVIZ server against a bare websockets server, in one run.

    .venv/bin/python scripts/bench/server.py [--short] [--json FILE] [--kitti DIR] [--client-procs N] [--tmp DIR] [--quick]

Every party is its own process:

* the server under test, ``python -m xviz_server serve --data-dir ROOT --port 0``;
* the reference: a bare websockets (asyncio API) + uvloop server that pre-loads
  the same frame files and, for each ``xviz/transform_log``, sends them all
  then a done message: the best any Python server can do on this machine;
* the clients, the same code against both: a minimal WebSocket client ("raw",
  asyncio on uvloop, counting bytes in place) with which the server is the
  bottleneck, and the websockets asyncio client, itself the bottleneck near
  1 GB/s per process, for what a Python viewer sees. 20 clients share one
  client process unless a row says otherwise: with 2 cores, server and
  clients compete for them, and the report shows each one's CPU use.

Sections:

1. whole-log throughput of the KITTI log, 1 and 20 clients, GLB as stored and
   transcoded to JSON, as a ratio to the reference (target: >= 0.8);
2. time to first frame, cold (first request after start) and warm;
3. point-in-time latency p50/p99 on a generated 100 000-frame log (10 000 with
   --short), on the same generator's 25-frame log and on KITTI, beside the
   loopback round trip (target: p99 < 5 ms, nearly independent of log length);
4. server peak RSS with 20 clients of which 5 stop reading, against the bound
   cache + 20 x (read-ahead + 1) x largest frame;
5. permessage-deflate off (the default) and on: payload and wire rates, bytes
   ratio, CPU cost.

The reference server and the clients are ``kit.peers``; the processes and
their accounting, ``kit.proc``; percentiles and generated logs, ``kit``.
Speed is reported as numbers and ratios against the reference measured in the
same run; nothing here asserts a time. The machine may be shared: each
measurement also says how many cores other processes used meanwhile.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import uvloop
import websockets

MB = 1e6  # rates in MB/s are 10^6 bytes per second
MIB = 1 << 20  # memory in MiB, like --cache-mb
QUIET = 0.25  # a trial is "quiet" when other processes used fewer cores than this

from kit import KITTI, REPO, metadata, parse, update
from kit.proc import Process, RssSampler, other_cores, other_cpu, rss_mib, run_clients, start_reference, start_server

#: ``--quick``: every section once, on a few megabytes (a check that the benchmark works, not a measurement).
SMOKE = False


# ================================================================ the generated log


def generate_log(directory: Path, count: int) -> Path:
    """A log of ``count`` small GLB state updates at 10 Hz, in the reference layout (with ``0-frame.json``).

    Each frame is the kit's ``update(t)`` (a pose, a 10-point cloud, a time
    series; SNAPSHOT), encoded once with a placeholder time whose digits
    are then replaced, at equal width, in each copy: 100 000 frames in seconds.
    """
    from xviz_server.codec import Format, decode, encode
    from xviz_server.layout import INDEX_FILE, METADATA_NUMBER, file_number, index_document

    placeholder = 123456.7
    template = encode({"type": "xviz/state_update", "data": update(placeholder)}, Format.BINARY)
    token, double = b"123456.7", b"246913.4"  # t, and the time series value 2t
    if template.count(token) < 2 or template.count(double) != 1:
        raise RuntimeError("cannot patch the frame template: the placeholder time is not where expected")
    if count > 100_000:
        raise ValueError("the fixed-width times cover at most 100 000 frames")
    directory.mkdir(parents=True)
    times = [f"{100000 + i / 10:.1f}" for i in range(count)]  # 100000.0 ... 109999.9: always 8 characters
    flags = os.O_WRONLY | os.O_CREAT | os.O_TRUNC

    def write(numbers: range) -> None:
        for i in numbers:
            text = times[i]
            data = template.replace(token, text.encode()).replace(double, f"{2 * float(text):.1f}".encode())
            fd = os.open(f"{directory}/{file_number(i)}-frame.glb", flags, 0o644)
            try:
                os.write(fd, data)
            finally:
                os.close(fd)

    with ThreadPoolExecutor(4) as pool:  # file creation is system calls: threads overlap them
        list(pool.map(write, [range(k, count, 4) for k in range(4)]))
    start, end = float(times[0]), float(times[-1])
    meta = metadata(start_time=start, end_time=end)
    (directory / f"{METADATA_NUMBER}-frame.glb").write_bytes(
        encode({"type": "xviz/metadata", "data": meta}, Format.BINARY)
    )
    (directory / INDEX_FILE).write_text(json.dumps(index_document([(float(t), float(t)) for t in times])))
    last = decode((directory / f"{file_number(count - 1)}-frame.glb").read_bytes())
    assert last["data"]["updates"][0]["timestamp"] == end, "generated frames carry the wrong time"
    return directory


# ================================================================ the run


def machine() -> dict[str, Any]:
    model = "?"
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            model = next((line.split(":", 1)[1].strip() for line in cpuinfo if line.startswith("model name")), "?")
    except OSError:
        pass
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], check=False, capture_output=True, text=True, cwd=REPO
    ).stdout.strip()
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no", "--", "xviz_server", "providers"],
        check=False,
        capture_output=True,
        text=True,
        cwd=REPO,
    ).stdout.strip()
    return {
        "cores": os.cpu_count(),
        "cpu": model,
        "kernel": platform.release(),
        "python": platform.python_version(),
        "websockets": websockets.__version__,
        "uvloop": uvloop.__version__,
        "server_code": f"git {commit}" + (" + uncommitted changes under xviz_server/ or providers/" if dirty else ""),
    }


def line(text: str = "") -> None:
    print(text, flush=True)


def section(title: str) -> None:
    line()
    line(title)
    line("-" * len(title))


def verdict(ok: bool) -> str:
    return "met" if ok else "NOT MET"


def median_run(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The median of several runs by MB/s, with every run's MB/s as the spread."""
    rates = [r["mb_s"] for r in runs]
    middle = sorted(runs, key=lambda r: r["mb_s"])[len(runs) // 2]
    return {**middle, "trials_mb_s": rates}


def throughput_section(
    args: argparse.Namespace, root: Path, reference: Process, results: dict[str, Any], quick: bool
) -> None:
    frames_in_log = len(list(args.kitti.glob("*-frame.glb"))) - 1
    n_trials = 1 if SMOKE else 2 if quick else 5
    # Bytes each trial moves: a window of about a second at the rates seen here.
    volume = {"raw": 2.5e9, "websockets": 0.8e9}
    if quick:
        volume = {kind: v / (500 if SMOKE else 2) for kind, v in volume.items()}
    section(f"1. Whole-log throughput, KITTI ({frames_in_log} frames)")
    line(
        f"Each client fetches the whole log N times after its metadata (N chosen so that a trial moves ~{volume['raw'] / 1e9:.1f} GB "
        f"with the raw client, ~{volume['websockets'] / 1e9:.1f} GB with websockets); {n_trials} trials, each a server run "
        "next to a reference run (order alternating); MB/s: median trial, all trials listed; ratio: median of the "
        "trials' server/reference ratios (robust to load from other processes changing during the run). MB/s counts message payload (10^6 B). CPU columns: cores used during the "
        "window by the server (or reference) process, by the client process(es), and by other processes on the machine "
        "(of the median trial; 1.00 is one core)."
    )
    with start_server(root) as server:
        kitti = server.url("kitti")
        # Warm: open the log, fill the cache with the GLB frames and their JSON transcoding.
        glb_bytes = run_clients({"task": "stream", "url": kitti, "clients": 1, "repeats": 1})["bytes"]
        json_bytes = run_clients({"task": "stream", "url": kitti + "?message_format=JSON", "clients": 1, "repeats": 1})[
            "bytes"
        ]
        configs = [("raw", 1, 1), ("raw", 20, 1), ("websockets", 1, 1), ("websockets", 20, 1)]
        if SMOKE:
            configs = [("raw", 1, 1)]
        if not quick:
            configs += [("raw", 20, 2), ("websockets", 20, 2)]
        if args.client_procs > 2:
            configs += [("raw", 20, args.client_procs), ("websockets", 20, args.client_procs)]
        rows = []
        for kind, clients, procs in configs:
            for fmt, query, log_bytes in (("GLB", "", glb_bytes), ("JSON", "?message_format=JSON", json_bytes)):
                repeats = max(1, round(volume[kind] / (clients * log_bytes)))
                spec = {"task": "stream", "clients": clients, "repeats": repeats, "client": kind}
                ours_runs, bare_runs = [], []
                for trial in range(n_trials):
                    for who in ("server", "reference") if trial % 2 == 0 else ("reference", "server"):
                        if who == "server":
                            ours_runs.append(run_clients({**spec, "url": kitti + query}, procs, server.pid))
                        else:
                            bare_runs.append(
                                run_clients({**spec, "url": reference.url("kitti") + query}, procs, reference.pid)
                            )
                mine, theirs = median_run(ours_runs), median_run(bare_runs)
                ratios = [a["mb_s"] / b["mb_s"] for a, b in zip(ours_runs, bare_runs)]
                quiet = [
                    a["mb_s"] / b["mb_s"]
                    for a, b in zip(ours_runs, bare_runs)
                    if max(a["other_cpu"], b["other_cpu"]) < QUIET
                ]
                for r in ours_runs + bare_runs:
                    if r["frames_per_request"] != [frames_in_log] or r["errors"]:
                        raise RuntimeError(
                            f"a request did not get {frames_in_log} frames: {r['frames_per_request']}, "
                            f"{r['errors']} errors"
                        )
                rows.append(
                    {
                        "client": kind,
                        "clients": clients,
                        "client_procs": procs,
                        "format": fmt,
                        "repeats": repeats,
                        "server": mine,
                        "reference": theirs,
                        "ratio": statistics.median(ratios),
                        "trial_ratios": ratios,
                        "quiet_ratio": statistics.median(quiet) if quiet else None,
                        "quiet_trials": len(quiet),
                    }
                )
    line()
    width = 5 * n_trials + 1
    line(
        f"{'client':<11}{'clients':<14}{'format':<7}{'':>10}{'MB/s':>7}{'frames/s':>9}  {'trials MB/s':<{width}}"
        f"{'srv CPU':>8}{'cli CPU':>8}{'others':>7}{'ratio':>7}{'quiet':>7}"
    )
    for row in rows:
        label = f"{row['clients']} x{row['repeats']}" + (f" {row['client_procs']}p" if row["client_procs"] > 1 else "")
        for who in ("server", "reference"):
            r = row[who]
            spread = "/".join(f"{x:.0f}" for x in r["trials_mb_s"])
            first = who == "server"
            line(
                f"{row['client'] if first else '':<11}{label if first else '':<14}{row['format'] if first else '':<7}{who:>10}"
                f"{r['mb_s']:7.0f}{r['frames_s']:9.0f}  {spread:<{width}}{r['server_cpu']:8.2f}{r['client_cpu']:8.2f}"
                f"{r['other_cpu']:7.2f}"
                + (f"{row['ratio']:7.2f}" if first else "")
                + ((f"{row['quiet_ratio']:7.2f}" if row["quiet_ratio"] is not None else f"{'-':>7}") if first else "")
            )
    line(
        "(clients 'N xR Kp': N clients each fetching the log R times, spread over K client processes; quiet: median "
        f"ratio of the trials in which other processes used under {QUIET} cores during both runs.)"
    )
    line()
    line("Trial ratios server/reference:")
    for row in rows:
        line(
            f"  {row['client']:<11}{row['clients']:>3} client(s){' ' + str(row['client_procs']) + ' procs' if row['client_procs'] > 1 else '':<8}"
            f" {row['format']:<5}" + " ".join(f"{x:.2f}" for x in row["trial_ratios"])
        )
    glb_rows = [r for r in rows if r["format"] == "GLB" and r["client_procs"] == 1]
    ok = all(r["ratio"] >= 0.8 for r in glb_rows)
    line()
    line(
        "GLB ratio server/reference: "
        + ", ".join(f"{r['client']} {r['clients']} client(s) {r['ratio']:.2f}" for r in glb_rows)
        + f"; target >= 0.8: {verdict(ok)}"
    )
    json_rows = [r for r in rows if r["format"] == "JSON" and r["client_procs"] == 1]
    line(
        "JSON-transcoded (transcoded once, then served from the cache; the reference sends the same JSON bytes, pre-encoded): "
        + ", ".join(f"{r['client']} {r['clients']} {r['ratio']:.2f}" for r in json_rows)
    )
    line(
        f"Average message: GLB {glb_bytes / frames_in_log / MB:.2f} MB, JSON {json_bytes / frames_in_log / MB:.2f} MB."
    )
    results["throughput"] = {"rows": rows, "target_met": ok}


def first_frame_section(root: Path, reference: Process, results: dict[str, Any], quick: bool) -> None:
    restarts = 1 if SMOKE else 3 if quick else 7
    warm = 5
    section("2. Time to first frame (transform_log sent -> first state update received)")
    line(
        f"Cold: the first request after server start (median of {restarts} fresh servers; frame files in the OS page cache). "
        f"Warm: the next {warm} requests on the same connection, interleaved with requests to the reference (pre-loaded), so "
        "both see the same load. JSON cold: then the first request of a JSON session (the first transcoding)."
    )
    values: dict[str, list[float]] = {
        "server GLB, cold": [],
        "server GLB, warm": [],
        "server JSON-transcoded, cold": [],
        "reference": [],
    }
    other = []
    for _ in range(restarts):
        with start_server(root) as server:
            targets = [
                {"name": "glb", "url": server.url("kitti"), "op": "first"},
                {"name": "json", "url": server.url("kitti") + "?message_format=JSON", "op": "first"},
                {"name": "ref", "url": reference.url("kitti"), "op": "first"},
            ]
            schedule = ["glb"] + ["ref", "glb"] * warm + ["ref", "json"]
            outcome = run_clients({"task": "latency", "targets": targets, "schedule": schedule})
        glb = outcome["glb"]["values_ms"]
        values["server GLB, cold"].append(glb[0])
        values["server GLB, warm"].extend(glb[1:])
        values["server JSON-transcoded, cold"].extend(outcome["json"]["values_ms"])
        values["reference"].extend(outcome["ref"]["values_ms"])
        other.append(outcome["other_cpu"])
    line()
    line(f"{'':<32}{'median ms':>10}{'min':>8}{'max':>8}{'n':>5}")
    for name, series in values.items():
        line(f"{name:<32}{statistics.median(series):10.2f}{min(series):8.2f}{max(series):8.2f}{len(series):>5}")
    line(
        f"(a first frame is a whole 2.1 MB message; other processes used {statistics.median(other):.2f} cores meanwhile, median)"
    )
    results["first_frame"] = {name: {"median_ms": statistics.median(v), "all_ms": v} for name, v in values.items()}


def point_in_time_section(
    root: Path, reference: Process, results: dict[str, Any], quick: bool, long_frames: int
) -> None:
    rounds = 20 if SMOKE else 500 if quick else 2000
    section("3. Point-in-time latency (random instants, fixed seed, one client, each answer awaited)")
    line(
        f"One fresh server serving all three logs; one client, one connection per row below, {rounds} rounds in which each "
        "connection in turn sends one request and awaits its answer (server and reference interleaved: same load for all)."
    )
    line(
        "Uncached: the first answer ending at a given frame (read, merged, encoded); cached: answers for a frame already "
        "asked about (the server caches answers by the frame they end at). Then a second pass on KITTI, all cached."
    )
    long_name = f"generated, {long_frames} frames"
    with start_server(root) as server:
        targets: list[dict[str, Any]] = [
            {"name": "loopback ping, reference", "url": reference.url("kitti"), "op": "ping"},
            {"name": "reference, one small frame", "url": reference.url("short"), "op": "pit"},
            {"name": "reference, one KITTI frame", "url": reference.url("kitti"), "op": "pit"},
            {"name": long_name, "url": server.url("long"), "op": "pit", "classify": True},
            {"name": "generated, 25 frames", "url": server.url("short"), "op": "pit", "classify": True},
            {"name": "KITTI, 25 frames", "url": server.url("kitti"), "op": "pit", "classify": True},
        ]
        names = [t["name"] for t in targets]
        first = run_clients({"task": "latency", "targets": targets, "schedule": names * rounds})
        again = [
            {**t, "name": t["name"] + ", 2nd pass"}
            for t in targets
            if t["name"] in ("reference, one KITTI frame", "KITTI, 25 frames")
        ]
        second = run_clients(
            {"task": "latency", "targets": again, "schedule": [t["name"] for t in again] * (rounds // 2)}
        )
        # The second pass is a new connection on the same server: its "uncached" list counts answers new to this
        # connection, all of which the server has cached by now.
        kitti_again = second["KITTI, 25 frames, 2nd pass"]
        kitti_again["cached"], kitti_again["uncached"] = kitti_again["all"], {"count": 0}
    rows = {name: first[name] for name in names}
    rows["reference, one KITTI frame, 2nd pass"] = second["reference, one KITTI frame, 2nd pass"]
    rows["KITTI, 25 frames, 2nd pass"] = kitti_again

    def pair(s: dict[str, Any]) -> str:
        return f"{s['p50_ms']:.2f}/{s['p99_ms']:.2f} ({s['count']})" if s.get("count") else "-"

    line()
    line(
        f"{'':<38}{'answer':>9}  {'p50 ms':>7}{'p99 ms':>8}{'max ms':>8}   {'uncached p50/p99 (n)':>22}   {'cached p50/p99 (n)':>20}"
    )
    for name, r in rows.items():
        s = r["all"]
        size = f"{r['answer_bytes'] / 1e3:7.1f}kB" if r.get("answer_bytes") else f"{'':9}"
        line(
            f"{name:<38}{size}  {s['p50_ms']:7.2f}{s['p99_ms']:8.2f}{s['max_ms']:8.2f}   "
            f"{pair(r['uncached']) if r['uncached'].get('count') or name.startswith(('gen', 'KITTI')) else '':>22}   "
            f"{pair(r['cached']) if r['cached'].get('count') or name.startswith(('gen', 'KITTI')) else '':>20}"
        )
    long_r, short_r, kitti_r = rows[long_name], rows["generated, 25 frames"], rows["KITTI, 25 frames"]
    line(
        f"(other processes used {first['other_cpu']:.2f} cores during the first pass, {second['other_cpu']:.2f} during the second)"
    )
    line()
    line(
        f"Time from connect to metadata (the log is opened on first use): {long_frames}-frame log "
        f"{long_r['to_metadata_ms']:.0f} ms, 25-frame log {short_r['to_metadata_ms']:.0f} ms, KITTI {kitti_r['to_metadata_ms']:.0f} ms."
    )
    ok_long = long_r["all"]["p99_ms"] < 5
    ok_kitti = kitti_r["all"]["p99_ms"] < 5
    uncached_p50 = long_r["uncached"]["p50_ms"] / short_r["uncached"]["p50_ms"]
    ok_uncached = kitti_r["uncached"]["p99_ms"] < 5
    line(
        f"Target p99 < 5 ms: {long_frames}-frame log {long_r['all']['p99_ms']:.2f} ms: {verdict(ok_long)}; KITTI, all "
        f"{kitti_r['all']['count']} queries {kitti_r['all']['p99_ms']:.2f} ms: {verdict(ok_kitti)}; KITTI, the "
        f"{kitti_r['uncached']['count']} uncached answers alone {kitti_r['uncached']['p99_ms']:.2f} ms (p50 "
        f"{kitti_r['uncached']['p50_ms']:.2f}): {verdict(ok_uncached)}; KITTI all cached (2nd pass) "
        f"{kitti_again['all']['p99_ms']:.2f} ms: {verdict(kitti_again['all']['p99_ms'] < 5)}."
    )
    line(
        f"(The KITTI p99 over all queries depends on how many there are: 25 uncached answers are {25 / kitti_r['all']['count']:.1%} "
        "of them here, so the p99 sits at the edge of the uncached ones.)"
    )
    line(
        f"Length independence (same small frames, {long_frames} vs 25 frames): uncached p50 {long_r['uncached']['p50_ms']:.2f} vs "
        f"{short_r['uncached']['p50_ms']:.2f} ms (ratio {uncached_p50:.2f}), uncached p99 {long_r['uncached']['p99_ms']:.2f} vs "
        f"{short_r['uncached']['p99_ms']:.2f} ms; all-request p50/p99 differ because nearly every query of the long log is "
        "uncached and nearly every one of the short log cached."
    )
    results["point_in_time"] = {
        "rows": {k: {kk: vv for kk, vv in v.items() if kk != "values_ms"} for k, v in rows.items()},
        "other_cpu": [first["other_cpu"], second["other_cpu"]],
        "target_met": ok_long and ok_kitti,
        "kitti_uncached_target_met": ok_uncached,
        "uncached_p50_ratio_long_to_short": uncached_p50,
    }


def memory_section(args: argparse.Namespace, root: Path, results: dict[str, Any], quick: bool) -> None:
    read_ahead = 4
    repeats = 1 if SMOKE else 3 if quick else 4
    n_trials = 1 if quick else 3
    frames_in_log = len(list(args.kitti.glob("*-frame.glb"))) - 1
    largest = max(p.stat().st_size for p in args.kitti.glob("*-frame.glb")) / MIB
    log_size = sum(p.stat().st_size for p in args.kitti.glob("*-frame.glb")) / MIB
    section("4. Server memory: 20 clients on KITTI, 5 of which stop reading after their first message")
    line(
        f"The 5 receive the metadata, send transform_log and never read again (transport paused); the 15 others (raw "
        f"client) fetch the whole log {repeats} times; {n_trials} trial(s) of each, alternating, on one server per cache size. "
        "RSS of the server process sampled every 10 ms (/proc/PID/status VmRSS); peak over all trials, MB/s median."
    )
    rows = []
    for cache_mb in (16,) if SMOKE else (256, 16):
        with start_server(root, "--cache-mb", str(cache_mb), "--read-ahead", str(read_ahead)) as server:
            time.sleep(0.5)
            baseline = rss_mib(server.pid)
            runs: dict[str, list[dict[str, Any]]] = {"15 alone": [], "15 + 5 stalled": []}
            for _ in range(n_trials):
                for name, stalled in (("15 alone", 0), ("15 + 5 stalled", 5)):
                    with RssSampler(server.pid) as sampler:
                        outcome = run_clients(
                            {
                                "task": "stream",
                                "url": server.url("kitti"),
                                "clients": 15,
                                "repeats": repeats,
                                "stalled": stalled,
                            },
                            1,
                            server.pid,
                        )
                    if outcome["frames_per_request"] != [frames_in_log] or outcome["errors"]:
                        raise RuntimeError(f"active clients did not get every frame: {outcome['frames_per_request']}")
                    runs[name].append(
                        {**outcome, "peak_mib": sampler.peak, "peak_with_children_mib": sampler.peak_total}
                    )
            phases = {}
            for name, outcomes in runs.items():
                middle = median_run(outcomes)
                phases[name] = {
                    "peak_mib": max(o["peak_mib"] for o in outcomes),
                    "peak_with_children_mib": max(o["peak_with_children_mib"] for o in outcomes),
                    "mb_s": middle["mb_s"],
                    "trials_mb_s": middle["trials_mb_s"],
                    "other_cpu": middle["other_cpu"],
                }
            active_ratio = statistics.median(
                b["mb_s"] / a["mb_s"] for a, b in zip(runs["15 alone"], runs["15 + 5 stalled"])
            )
            after = rss_mib(server.pid)
        # Bound: the cache, plus per session the frames read ahead and one serialized frame in the socket's buffer.
        session_budget = (read_ahead + 1) * largest
        bound = baseline + cache_mb + 20 * session_budget
        rows.append(
            {
                "cache_mb": cache_mb,
                "baseline_mib": baseline,
                "after_mib": after,
                "phases": phases,
                "active_ratio": active_ratio,
                "session_budget_mib": session_budget,
                "bound_mib": bound,
                "within_bound": all(p["peak_mib"] <= bound for p in phases.values()),
            }
        )
    line()
    line(
        f"Largest frame {largest:.2f} MiB, whole log {log_size:.0f} MiB; read-ahead {read_ahead}. "
        f"Bound = RSS after start + cache + 20 x (read-ahead + 1) x largest frame."
    )
    line(
        f"{'--cache-mb':>10}{'after start':>12}{'peak 15 alone':>15}{'peak 15+5 stalled':>19}{'bound':>8}  "
        "15 active clients' MB/s: alone / beside 5 stalled (median trial ratio)"
    )
    for row in rows:
        a, b = row["phases"]["15 alone"], row["phases"]["15 + 5 stalled"]
        line(
            f"{row['cache_mb']:>10}{row['baseline_mib']:>10.0f}Mi{a['peak_mib']:>13.0f}Mi{b['peak_mib']:>17.0f}Mi"
            f"{row['bound_mib']:>6.0f}Mi  {a['mb_s']:.0f} / {b['mb_s']:.0f} ({row['active_ratio']:.2f}); trials "
            + " ".join(f"{x:.0f}" for x in a["trials_mb_s"])
            + " / "
            + " ".join(f"{x:.0f}" for x in b["trials_mb_s"])
        )
    ok = all(r["within_bound"] for r in rows)
    line()
    line(
        f"Peak within the bound: {verdict(ok)}. (--cache-mb 16 holds fewer frames than the log: sessions then keep "
        "their own read-ahead copies, which is what the per-session budget is for.)"
    )
    results["memory"] = {"rows": rows, "read_ahead": read_ahead, "largest_frame_mib": largest, "target_met": ok}


def deflate_section(root: Path, results: dict[str, Any], quick: bool) -> None:
    repeats_off = 1 if SMOKE else 2 if quick else 4
    section("5. permessage-deflate (1 client, KITTI; the client offers deflate, as websockets does by default)")
    rows = []
    for label, flags in (("off (default)", ()), ("--compression", ("--compression",))):
        with start_server(root, *flags) as server:
            for fmt, query in (("GLB", ""), ("JSON", "?message_format=JSON"))[: 1 if SMOKE else 2]:
                url = server.url("kitti") + query
                run_clients({"task": "stream", "url": url, "clients": 1, "repeats": 1})  # warm the cache (raw client)
                outcome = run_clients(
                    {
                        "task": "stream",
                        "url": url,
                        "clients": 1,
                        "client": "websockets",
                        "compression": "deflate",
                        "repeats": 1 if flags else repeats_off,
                    },
                    1,
                    server.pid,
                )
                rows.append({"deflate": label, "format": fmt, **outcome})
    line()
    line(
        f"{'server':<15}{'format':<7}{'negotiated':<12}{'payload MB/s':>13}{'wire MB/s':>10}{'frames/s':>9}"
        f"{'wire/payload':>13}{'srv CPU ms/frame':>17}{'cli CPU ms/frame':>17}{'others':>7}"
    )
    for r in rows:
        negotiated = "deflate" if r["extensions"] and "permessage-deflate" in r["extensions"] else "no"
        line(
            f"{r['deflate']:<15}{r['format']:<7}{negotiated:<12}{r['mb_s']:13.1f}{r['wire_mb_s']:10.1f}{r['frames_s']:9.1f}"
            f"{r['wire_bytes'] / r['bytes']:13.3f}{r['server_cpu_s'] / r['frames'] * 1000:17.1f}"
            f"{r['client_cpu_s'] / r['frames'] * 1000:17.1f}{r['other_cpu']:7.2f}"
        )
    by = {(r["deflate"], r["format"]): r for r in rows}
    line()
    for fmt in sorted({r["format"] for r in rows}):
        off, on = by[("off (default)", fmt)], by[("--compression", fmt)]
        line(
            f"{fmt}: deflate sends {on['wire_bytes'] / on['bytes']:.0%} of the bytes at {on['mb_s'] / off['mb_s']:.2f}x the "
            f"payload rate; it delivers more only over links slower than the ~{on['mb_s']:.0f} MB/s (~{on['mb_s'] * 8:.0f} Mbit/s) "
            "of payload it sustains, and that is one server core's worth, shared by every deflate session."
        )
    line(
        "(The 'off' rows are limited by the websockets client, about one core per GB/s, and by other processes: 'others' "
        "is the cores they used meanwhile.)"
    )
    results["deflate"] = {"rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--kitti", type=Path, default=KITTI, help=f"the KITTI GLB log (default {KITTI})")
    parser.add_argument(
        "--short", action="store_true", help="fewer repeats and a 10 000-frame long log (under ~2 minutes)"
    )
    parser.add_argument("--json", type=Path, help="also write the numbers to this file")
    parser.add_argument(
        "--client-procs",
        type=int,
        default=1,
        help="also run the 20-client throughput rows with this many client processes (rows with 1, and "
        "2 in a full run, are always there)",
    )
    parser.add_argument(
        "--long-frames", type=int, help="frames of the generated long log (default 100 000; 10 000 with --short)"
    )
    shm = Path("/dev/shm")
    parser.add_argument(
        "--tmp",
        type=Path,
        default=shm if shm.is_dir() and os.access(shm, os.W_OK) else None,
        help="where to write the generated logs (default /dev/shm, a RAM disk: 100 000 small files are "
        "written in ~2 s there and can take a minute on a busy disk)",
    )
    args = parse(parser, quick={"short": True, "long_frames": 200})
    global SMOKE
    SMOKE = args.quick

    began = time.perf_counter()
    quick = args.short
    long_frames = args.long_frames or (10_000 if quick else 100_000)
    info = machine()
    results: dict[str, Any] = {
        "machine": info,
        "quick": quick,
        "long_frames": long_frames,
        "sections": {},
        "load_average_at_start": os.getloadavg(),
    }
    line(
        f"xviz-server benchmark ({'smoke' if SMOKE else 'short' if quick else 'full'} run), {time.strftime('%Y-%m-%d %H:%M:%S')}"
    )
    line(
        f"machine: {info['cores']} cores ({info['cpu']}), Linux {info['kernel']}, Python {info['python']}, "
        f"websockets {info['websockets']}, uvloop {info['uvloop']}; load average at start "
        + " ".join(f"{x:.2f}" for x in os.getloadavg())
    )
    line(f"server under test: {info['server_code']}, run as `python -m xviz_server serve` (uvloop)")
    line("reference: a bare websockets + uvloop server sending the same frames, pre-loaded in memory.")
    line(
        "clients: separate processes, asyncio on uvloop: 'raw' (a minimal WebSocket client that counts bytes in place: the "
        "server is the bottleneck) and 'websockets' (the websockets client: about one core per ~1 GB/s, so the client is the "
        "bottleneck). Server, reference and clients share the 2 cores; 20 clients run in 1 client process unless a row "
        "says otherwise."
    )
    with tempfile.TemporaryDirectory(prefix="xviz-bench-", dir=args.tmp) as scratch:
        # Two data roots: KITTI alone, and KITTI with the generated logs (100 000 files to list at start).
        root, pit_root = Path(scratch) / "logs", Path(scratch) / "pit-logs"
        if SMOKE:  # the KITTI log's first 3 frames (the server indexes them itself)
            head = Path(scratch) / "kitti-head"
            head.mkdir()
            for number in range(1, 5):
                (head / f"{number}-frame.glb").symlink_to((args.kitti / f"{number}-frame.glb").resolve())
            args.kitti = head
        for directory in (root, pit_root):
            directory.mkdir()
            (directory / "kitti").symlink_to(args.kitti.resolve())
        started = time.perf_counter()
        generate_log(pit_root / "long", long_frames)
        generated_s = time.perf_counter() - started
        generate_log(pit_root / "short", 25)
        frames = len(list(args.kitti.glob("*-frame.glb"))) - 1
        total = sum(p.stat().st_size for p in args.kitti.glob("*-frame.glb")) / MB
        line(
            f"KITTI log: {args.kitti} ({frames} frames + metadata, {total:.1f} MB); generated a {long_frames}-frame log "
            f"(small GLB frames, SNAPSHOT) in {generated_s:.1f} s under {scratch}"
        )
        results["generate_seconds"] = generated_s

        def timed(name: str, function: Any, *arguments: Any) -> None:
            started, cpu = time.perf_counter(), other_cpu()
            function(*arguments)
            seconds, other = time.perf_counter() - started, other_cores(cpu, started)
            line(f"[{seconds:.0f} s; other processes on the machine used {other:.2f} cores on average meanwhile]")
            results["sections"][name] = {"seconds": seconds, "other_cores": other}

        with start_reference({"kitti": args.kitti, "short": pit_root / "short"}) as reference:
            timed("throughput", throughput_section, args, root, reference, results, quick)
            timed("first_frame", first_frame_section, root, reference, results, quick)
            timed("point_in_time", point_in_time_section, pit_root, reference, results, quick, long_frames)
        timed("memory", memory_section, args, root, results, quick)
        timed("deflate", deflate_section, root, results, quick)
    results["seconds"] = time.perf_counter() - began
    line()
    line(f"ran in {results['seconds']:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2, default=str))
        line(f"numbers written to {args.json}")


if __name__ == "__main__":
    main()
