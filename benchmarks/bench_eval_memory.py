"""Memory of ``lerobot-eval --env.type=actionflow``: peak PSS of its process tree, per process
and, for the env workers, per mapping.

Runs ``lerobot-eval`` on a tiny untrained ActionFlow checkpoint
(``lerobot_actionflow.evaluation.untrained``) in its own session and samples every process of that
session every ``--interval`` seconds from ``/proc/<pid>/smaps_rollup``. PSS (proportional set
size) charges each page to the processes mapping it in equal parts, so the sum over processes
counts a page shared copy-on-write between the forkserver and its workers once. At every new
peak of the sum (and at most every 2 s) the full ``/proc/<pid>/smaps`` of each env worker is
read and its mappings grouped by file (anonymous memory under ``[anon]``, the brk heap under
``[heap]``); the report keeps the breakdown taken at the peak.

Processes are labelled ``main`` (the ``lerobot-eval`` process), ``forkserver``,
``resource_tracker`` and ``worker`` (children of the forkserver: the AsyncVectorEnv workers).

    PYTHONPATH=. HF_HUB_OFFLINE=1 MUJOCO_GL=egl PYOPENGL_PLATFORM=egl WANDB_MODE=disabled \\
        .venv/bin/python benchmarks/bench_eval_memory.py [--batch-size 4] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

_ROLLUP_KEYS = ("Rss", "Pss", "Shared_Clean", "Shared_Dirty", "Private_Clean", "Private_Dirty", "Swap")
_MAP_KEYS = ("Pss", "Shared_Clean", "Shared_Dirty", "Private_Clean", "Private_Dirty")


def _kib_fields(text: str, keys: tuple[str, ...]) -> dict[str, int]:
    out = dict.fromkeys(keys, 0)
    for line in text.splitlines():
        name, _, rest = line.partition(":")
        if name in out:
            out[name] += int(rest.split()[0])
    return out


def _read(path: str) -> str | None:
    try:
        with open(path) as f:
            return f.read()
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        return None


def session_processes(sid: int) -> dict[int, tuple[int, str]]:
    """``{pid: (ppid, cmdline)}`` of every live process in session ``sid``."""
    procs = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        stat = _read(f"/proc/{entry}/stat")
        if stat is None:
            continue
        fields = stat[stat.rindex(")") + 2 :].split()  # after "pid (comm) "
        if int(fields[3]) != sid:  # state ppid pgrp session
            continue
        cmd = (_read(f"/proc/{entry}/cmdline") or "").replace("\0", " ").strip()
        procs[int(entry)] = (int(fields[1]), cmd)
    return procs


def label(pid: int, root: int, procs: dict[int, tuple[int, str]]) -> str:
    ppid, cmd = procs[pid]
    if pid == root:
        return "main"
    if ppid in procs and ppid != root and "forkserver" in procs[ppid][1]:
        return "worker"  # forked by the forkserver (whose command line it keeps)
    if "forkserver" in cmd:
        return "forkserver"
    if "resource_tracker" in cmd:
        return "resource_tracker"
    return "other"


def mapping_breakdown(pid: int) -> dict[str, dict[str, int]] | None:
    """KiB per mapping name (file path, ``[heap]``, ``[anon]``, ``[stack]``...) of one process."""
    text = _read(f"/proc/{pid}/smaps")
    if text is None:
        return None
    groups: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(_MAP_KEYS, 0))
    name = "[anon]"
    for line in text.splitlines():
        head = line.split(None, 5)
        if "-" in head[0] and ":" not in head[0]:  # a mapping header: range perms offset dev inode [path]
            name = head[5].strip() if len(head) > 5 else "[anon]"
            if name.startswith("[anon:"):
                name = "[anon]"
            continue
        key, _, rest = line.partition(":")
        if key in _MAP_KEYS:
            groups[name][key] += int(rest.split()[0])
    return dict(groups)


def group_by_library(groups: dict[str, dict[str, int]]) -> dict[str, dict[str, int]]:
    """Merge the mappings of one file into one row, keyed by a short name (site-packages relative)."""
    out: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(_MAP_KEYS, 0))
    for name, vals in groups.items():
        short = name.split("site-packages/")[-1] if "site-packages/" in name else name
        for k, v in vals.items():
            out[short][k] += v
    return dict(out)


def run(args) -> dict:
    from lerobot_actionflow.evaluation.untrained import save_untrained_actionflow

    work = Path(args.work_dir or tempfile.mkdtemp(prefix="evalmem-"))
    ckpt = Path(args.checkpoint) if args.checkpoint else save_untrained_actionflow(args.task, work / "policy")
    out_dir = work / f"eval-{int(time.time())}"
    cmd = [
        str(Path(sys.executable).with_name("lerobot-eval")), f"--policy.path={ckpt}", "--policy.device=cpu",
        "--env.type=actionflow", f"--env.task={args.task}", f"--env.episode_length={args.episode_length}",
        f"--env.visualization_height={args.render_size}", f"--env.visualization_width={args.render_size}",
        f"--eval.n_episodes={args.n_episodes or args.batch_size}", f"--eval.batch_size={args.batch_size}",
        f"--output_dir={out_dir}", "--seed=3",
    ]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1", "WANDB_MODE": "disabled"}
    env.setdefault("MUJOCO_GL", "egl")
    env.setdefault("PYOPENGL_PLATFORM", "egl")
    t0 = time.monotonic()
    proc = subprocess.Popen(
        cmd, env=env, cwd=work, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT
    )
    root = proc.pid
    peak = {"pss_kib": 0}
    breakdown_total, breakdown_t = 0, -1e9
    timeline = []
    log_lines: list[bytes] = []
    os.set_blocking(proc.stdout.fileno(), False)
    while True:
        chunk = proc.stdout.read()
        if chunk:
            log_lines.append(chunk)
        done = proc.poll() is not None
        procs = session_processes(root)
        rows = []
        for pid in procs:
            text = _read(f"/proc/{pid}/smaps_rollup")
            if text is None:
                continue
            rows.append({"pid": pid, "role": label(pid, root, procs), **_kib_fields(text, _ROLLUP_KEYS)})
        total = sum(r["Pss"] for r in rows)
        t = round(time.monotonic() - t0, 2)
        timeline.append((t, len(rows), total))
        if total > peak["pss_kib"]:
            mappings = {k: peak[k] for k in ("worker_mappings", "mappings_t_s") if k in peak}
            peak = {"pss_kib": total, "t_s": t, "n_processes": len(rows), "processes": rows, **mappings}
            workers = [r["pid"] for r in rows if r["role"] == "worker"]
            if workers and (total > breakdown_total * 1.01 or t - breakdown_t > 2.0):
                maps = {pid: mapping_breakdown(pid) for pid in workers}
                peak["worker_mappings"] = {pid: m for pid, m in maps.items() if m is not None}
                peak["mappings_t_s"] = t
                breakdown_total, breakdown_t = total, t
        if done:
            break
        time.sleep(args.interval)
    rest = proc.stdout.read()
    if rest:
        log_lines.append(rest)
    log = b"".join(log_lines).decode(errors="replace")
    if proc.returncode != 0:
        raise SystemExit(f"lerobot-eval failed ({proc.returncode}):\n{log[-4000:]}")
    return {
        "command": " ".join(cmd),
        "env": {k: env.get(k) for k in ("OMP_NUM_THREADS", "MUJOCO_GL", "PYOPENGL_PLATFORM", "PYTHONPATH")},
        "machine": {
            "cpu": platform.processor() or platform.machine(),
            "cores": os.cpu_count(),
            "load": os.getloadavg(),
        },
        "wall_s": round(time.monotonic() - t0, 1),
        "interval_s": args.interval,
        "peak": peak,
        "timeline": timeline,
        "eval_info": json.loads((out_dir / "eval_info.json").read_text()).get("overall"),
    }


def summarise(result: dict, top: int) -> str:
    peak = result["peak"]
    mib = 1024
    lines = [
        f"peak PSS {peak['pss_kib'] / mib:.0f} MiB over {peak['n_processes']} processes at t={peak['t_s']} s "
        f"(run {result['wall_s']} s)",
        f"{'role':<17}{'pid':>8}{'PSS':>8}{'Rss':>8}{'PrivD':>8}{'PrivC':>8}{'Shared':>8}  (MiB)",
    ]
    for r in sorted(peak["processes"], key=lambda r: r["role"]):
        shared = r["Shared_Clean"] + r["Shared_Dirty"]
        lines.append(
            f"{r['role']:<17}{r['pid']:>8}{r['Pss'] / mib:>8.0f}{r['Rss'] / mib:>8.0f}"
            f"{r['Private_Dirty'] / mib:>8.0f}{r['Private_Clean'] / mib:>8.0f}{shared / mib:>8.0f}"
        )
    maps = peak.get("worker_mappings") or {}
    if maps:
        pid, groups = sorted(maps.items())[0]
        libs = group_by_library(groups)
        lines.append(f"worker {pid} by mapping at t={peak['mappings_t_s']} s (top {top} by PSS; MiB):")
        lines.append(f"{'PSS':>8}{'PrivD':>8}{'PrivC':>8}{'Shared':>8}  mapping")
        for name, v in sorted(libs.items(), key=lambda kv: -kv[1]["Pss"])[:top]:
            shared = v["Shared_Clean"] + v["Shared_Dirty"]
            lines.append(
                f"{v['Pss'] / mib:>8.1f}{v['Private_Dirty'] / mib:>8.1f}{v['Private_Clean'] / mib:>8.1f}"
                f"{shared / mib:>8.1f}  {name}"
            )
        tot = {k: sum(v[k] for v in libs.values()) for k in _MAP_KEYS}
        lines.append(
            f"{tot['Pss'] / mib:>8.1f}{tot['Private_Dirty'] / mib:>8.1f}{tot['Private_Clean'] / mib:>8.1f}"
            f"{(tot['Shared_Clean'] + tot['Shared_Dirty']) / mib:>8.1f}  total"
        )
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--task", default="Lift")
    p.add_argument("--batch-size", type=int, default=4)
    p.add_argument("--n-episodes", type=int, default=None, help="default: the batch size")
    p.add_argument("--episode-length", type=int, default=40)
    p.add_argument("--render-size", type=int, default=64, help="--env.visualization_height/width")
    p.add_argument("--interval", type=float, default=0.5)
    p.add_argument("--checkpoint", default=None, help="a policy checkpoint (default: a tiny one, made)")
    p.add_argument("--work-dir", default=None)
    p.add_argument("--top", type=int, default=15)
    p.add_argument("--json", default=None, help="write the full result here")
    args = p.parse_args()
    result = run(args)
    print(summarise(result, args.top))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
