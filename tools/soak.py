#!/usr/bin/env python3
"""Soak benchmark of a continual pipeline run: does a long run stay healthy?

Runs `supervisor run` on each config as a continual run (its `run.updates` removed, recording
split into small parts) for a while, and meanwhile scales the workers up and down, issues
`supervisor set` changes, SIGKILLs a worker and the recorder now and then. Every few seconds it
samples each process's RSS (/proc/PID/status VmRSS) and open file descriptors (/proc/PID/fd),
the run's /dev/shm files and bytes, the recording's size and the update count (`supervisor
status`). At the end it stops the run, looks for what it left behind, runs
`mcap-tool analyze --verify` on the recording and prints a table.

It measures; it asserts nothing (a slow machine gives other figures, not a failure).

    tools/soak.py                                  # A1 and T-ball, 3 minutes each
    tools/soak.py --minutes 10 --config config/A1.toml
    tools/soak.py --bin-dir target/release --out /tmp/soak

Binaries: `--bin-dir`, else $CARGO_TARGET_DIR/release, else target/release (build them with
`cargo build --release -p supervisor -p record`). Standard library only.
"""

import argparse
import os
import random
import re
import signal
import subprocess
import sys
import time
import tomllib
from collections import Counter, defaultdict

KINDS = ["supervisor", "updater", "sampler", "recorder", "rollout-worker"]


def kib(path, key):
    """A `key:   N kB` line of /proc/PID/status, in KiB (None if the process is gone)."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1])
    except OSError:
        return None
    return None


def fds(pid):
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None


def shm_usage(prefix):
    """(files, bytes written (tmpfs blocks), bytes as `ls -l`) of /dev/shm files with prefix."""
    files = written = size = 0
    try:
        names = os.listdir("/dev/shm")
    except OSError:
        return 0, 0, 0
    for name in names:
        if not name.startswith(prefix):
            continue
        try:
            st = os.stat(os.path.join("/dev/shm", name))
        except OSError:
            continue
        files += 1
        written += st.st_blocks * 512
        size += st.st_size
    return files, written, size


def part_number(path):
    m = re.search(r"\.part-(\d+)\.mcap$", path)
    return int(m.group(1)) if m else 1


def tree_files(path):
    n = 0
    for _, dirs, files in os.walk(path):
        n += len(files) + len(dirs)
    return n


def continual_config(src, dst, split_mb):
    """The config without `run.updates` (continual), recording split at `split_mb`."""
    text = open(src).read()
    out, section = [], None
    for line in text.splitlines():
        m = re.match(r"^\s*\[+([^\]]+)\]+", line)
        if m:
            section = m.group(1).strip()
        if section == "run" and re.match(r"^\s*updates\s*=", line):
            continue
        out.append(line)
    if "[recording]" not in text:
        out += ["", "[recording]", f"split_mb = {split_mb}"]
    with open(dst, "w") as f:
        f.write("\n".join(out) + "\n")
    return tomllib.loads(text)


def set_values(cfg):
    """A setting to change and the values to alternate: the schedule's, or none."""
    for s in cfg.get("schedule", []):
        name, value = s.get("set"), s.get("value")
        task = next(iter(cfg.get("task", {}).values()), {})
        if name and isinstance(value, (int, float)):
            base = task.get(name, value)
            return name, [value, base] if base != value else [value, value * 1.1]
    return None, []


class Soak:
    def __init__(self, args, config, run_id):
        self.args, self.config, self.run_id = args, config, run_id
        self.hex = f"{run_id:016x}"
        self.name = os.path.splitext(os.path.basename(config))[0]
        self.dir = os.path.join(args.out, self.name)
        os.makedirs(self.dir, exist_ok=True)
        for f in os.listdir(self.dir):
            if f.endswith(".mcap"):
                os.remove(os.path.join(self.dir, f))
        self.cfg_path = os.path.join(self.dir, "continual.toml")
        self.cfg = continual_config(config, self.cfg_path, args.split_mb)
        self.setting, self.values = set_values(self.cfg)
        self.record = os.path.join(self.dir, f"{self.name}.mcap")
        self.samples = []  # (t, updates, {pid: (kind, rss, fds)}, shm, rec_bytes, parts)
        self.events = Counter()
        self.failed_events = Counter()
        self.deleted, self.deleted_parts = 0, 0

    def bin(self, name):
        return os.path.join(self.args.bin_dir, name)

    def ctl(self, *cmd, timeout=20):
        try:
            p = subprocess.run(
                [self.bin("supervisor"), *cmd, "--run", self.hex],
                capture_output=True,
                text=True,
                timeout=timeout,
                env=self.env,
            )
            return p.returncode, p.stdout + p.stderr
        except subprocess.TimeoutExpired:
            return -1, "timeout"

    def status(self):
        code, out = self.ctl("status")
        if code != 0:
            return None, {}, 0
        m = re.search(r"^updates: (\d+)", out, re.M)
        w = re.search(r"^workers: (\d+) running", out, re.M)
        pids = {}
        for line in out.splitlines():
            m2 = re.match(r"^\s+(\S+) pid (\d+) incarnation", line)
            if m2:
                kind = m2.group(1)
                kind = "rollout-worker" if kind.startswith("worker") else kind
                pids[int(m2.group(2))] = kind
        return (int(m.group(1)) if m else 0), pids, (int(w.group(1)) if w else 0)

    def sample(self, t):
        updates, pids, workers = self.status()
        if updates is None:
            return None
        pids[self.proc.pid] = "supervisor"
        procs = {}
        for pid, kind in pids.items():
            rss = kib(f"/proc/{pid}/status", "VmRSS")
            if rss is not None:
                threads = kib(f"/proc/{pid}/status", "Threads")
                procs[pid] = (kind, rss, fds(pid), threads)
        parts = [
            os.path.join(self.dir, f)
            for f in os.listdir(self.dir)
            if f.startswith(self.name) and f.endswith(".mcap")
        ]
        parts.sort(key=part_number)
        # Finished parts beyond the newest `keep_parts` are deleted (archived), as a long run's
        # user would: at full speed A1 writes ~3 GB a minute. Never the two newest (the one
        # being written, and one a dead recorder left, recovered in the background).
        keep = max(self.args.keep_parts, 2)
        for old in parts[:-keep] if self.args.keep_parts else []:
            try:
                self.deleted += os.path.getsize(old)
                os.remove(old)
                self.deleted_parts += 1
            except OSError:
                pass
        rec = self.deleted + sum(os.path.getsize(p) for p in parts if os.path.exists(p))
        root = f"/tmp/p2c-{self.hex}"
        shm = shm_usage(f"p2c{self.hex}_") + (tree_files(root) if os.path.exists(root) else 0,)
        self.samples.append((t, updates, procs, shm, rec, len(parts), workers))
        return updates, pids

    def act(self, step, pids):
        w = self.args.workers
        kind = ["scale-up", "set", "kill-worker", "scale-down", "kill-recorder", "set"][step % 6]
        ok = True
        if kind == "scale-up":
            ok = self.ctl("scale", "--workers", str(w + 3))[0] == 0
        elif kind == "scale-down":
            ok = self.ctl("scale", "--workers", str(w))[0] == 0
        elif kind == "set":
            if not self.setting:
                return
            v = self.values[self.events["set"] % len(self.values)]
            ok = self.ctl("set", self.setting, repr(v))[0] == 0
        else:
            want = "rollout-worker" if kind == "kill-worker" else "recorder"
            victims = [p for p, k in pids.items() if k == want]
            if not victims:
                ok = False
            else:
                try:
                    os.kill(random.choice(victims), signal.SIGKILL)
                except OSError:
                    ok = False
        self.events[kind] += 1
        if not ok:
            self.failed_events[kind] += 1

    def run(self):
        self.env = dict(os.environ, PI2CMA_RUN_DIR=os.path.join(self.dir, "runs"))
        cmd = [
            self.bin("supervisor"),
            "run",
            self.cfg_path,
            "--run-id",
            self.hex,
            "--workers",
            str(self.args.workers),
            "--record",
            self.record,
            "--bin-dir",
            self.args.bin_dir,
        ]
        self.log = open(os.path.join(self.dir, "supervisor.log"), "w")
        self.proc = subprocess.Popen(
            cmd, stdout=self.log, stderr=subprocess.STDOUT, cwd=self.dir, env=self.env
        )
        start = time.monotonic()
        duration = self.args.minutes * 60
        next_event, step = start + self.args.event_s, 0
        while True:
            now = time.monotonic()
            if now - start >= duration or self.proc.poll() is not None:
                break
            got = self.sample(now - start)
            if got and now >= next_event:
                self.act(step, got[1])
                step += 1
                next_event = now + self.args.event_s
            time.sleep(self.args.sample_s)
        if self.proc.poll() is None:
            # End at the worker count it began with, so start, middle and end compare alike.
            self.ctl("scale", "--workers", str(self.args.workers))
            for _ in range(3):
                time.sleep(self.args.sample_s)
                self.sample(time.monotonic() - start)
        self.elapsed = time.monotonic() - start
        early = self.proc.poll()
        if early is None:
            self.ctl("stop", timeout=60)
            try:
                self.exit = self.proc.wait(timeout=90)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.exit = "killed after 90 s"
        else:
            self.exit = f"{early} (ended by itself after {self.elapsed:.0f} s)"
        self.log.close()
        time.sleep(1)
        self.leftover_shm = shm_usage(f"p2c{self.hex}_")
        root = f"/tmp/p2c-{self.hex}"
        self.leftover_root = tree_files(root) if os.path.exists(root) else 0
        self.leftover_procs = self.survivors()
        self.verify()
        with open(os.path.join(self.dir, "samples.csv"), "w") as f:
            f.write("t,updates,workers,shm_files,shm_written,recording,pid,kind,rss_kib,fds,threads\n")
            for t, u, procs, shm, rec, _, w in self.samples:
                for pid, (kind, rss, fd, thr) in procs.items():
                    f.write(f"{t:.1f},{u},{w},{shm[0]},{shm[1]},{rec},{pid},{kind},{rss},{fd},{thr}\n")

    def survivors(self):
        n = 0
        for pid in {p for s in self.samples for p in s[2]}:
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    if self.hex.encode() in f.read():
                        n += 1
            except OSError:
                pass
        return n

    def verify(self):
        parts = sorted(
            (f for f in os.listdir(self.dir) if f.startswith(self.name) and f.endswith(".mcap")),
            key=part_number,
        )
        self.parts = parts
        if not parts:
            self.verified = "no recording"
            return
        t = time.monotonic()
        p = subprocess.run(
            [self.bin("mcap-tool"), "analyze", *parts, "--verify", "--no-csv", "--no-plots",
             "--out", "analysis"],
            capture_output=True,
            text=True,
            cwd=self.dir,
        )
        with open(os.path.join(self.dir, "analyze.log"), "w") as f:
            f.write(p.stdout + p.stderr)
        runs = re.search(r"one run of \d+ updates[^\n]*", p.stdout + p.stderr)
        self.verified = (
            f"{'PASS' if p.returncode == 0 else 'FAIL (exit %d)' % p.returncode} "
            f"in {time.monotonic() - t:.0f} s" + (f"; {runs.group(0)[:160]}" if runs else "")
        )

    def report(self):
        s = self.samples
        if len(s) < 3:
            print(f"{self.name}: too few samples ({len(s)}); exit {self.exit}")
            return
        T = s[-1][0]
        # Samples at the base worker count (scale-ups add ports, pipes and processes).
        base = [x for x in s if x[6] == self.args.workers] or s
        mid = min(base, key=lambda x: abs(x[0] - T / 2))
        marks = [base[0], mid, base[-1]]
        print(f"\n== {self.name}: {self.config}, {self.elapsed:.0f} s, {s[-1][1]} updates, "
              f"{self.args.workers}..{self.args.workers + 3} workers, split_mb {self.args.split_mb}")
        print("events: " + ", ".join(f"{k} {v}" for k, v in sorted(self.events.items()))
              + ("; failed: " + ", ".join(f"{k} {v}" for k, v in self.failed_events.items())
                 if self.failed_events else ""))
        print(f"{'process':<15}{'RSS MiB start/mid/end':>24}{'KiB/1000 upd':>14}"
              f"{'fds start/mid/end':>20}{'pids seen':>11}")
        for kind in KINDS:
            def at(x, what):
                vals = [p[what] for p in x[2].values() if p[0] == kind]
                return max(vals) if vals else None

            rss = [at(x, 1) for x in marks]
            fd = [at(x, 2) for x in marks]
            slope = self.slope(kind, T)
            seen = len({p for x in s for p, v in x[2].items() if v[0] == kind})
            fmt = lambda v, f: "-" if v is None else f(v)
            print(f"{kind:<15}"
                  f"{'/'.join(fmt(v, lambda a: f'{a / 1024:.1f}') for v in rss):>24}"
                  f"{fmt(slope, lambda a: f'{a:+.1f}'):>14}"
                  f"{'/'.join(fmt(v, str) for v in fd):>20}{seen:>11}")
        thr = [max((p[3] or 0 for p in x[2].values() if p[0] == "supervisor"), default=0)
               for x in marks]
        print("(start/mid/end: samples at the base worker count; several processes of a kind: "
              "the largest; KiB/1000 upd: least-squares slope of RSS over updates in the run's "
              "second half at the base worker count, of the longest-lived pid)")
        print(f"supervisor threads {'/'.join(map(str, thr))}")
        shm = [x[3] for x in marks]
        print("/dev/shm files " + "/".join(str(v[0]) for v in shm)
              + ", written KiB " + "/".join(str(v[1] // 1024) for v in shm)
              + ", ls -l MiB " + "/".join(f"{v[2] / 2**20:.1f}" for v in shm)
              + f"; peak written {max(x[3][1] for x in s) // 1024} KiB; entries under "
              f"/tmp/p2c-{self.hex} " + "/".join(str(v[3]) for v in shm))
        print(f"recording {s[-1][4] / 2**20:.1f} MiB in {len(self.parts) + self.deleted_parts}"
              f" files ({self.deleted_parts} older ones deleted as it ran) "
              f"({s[-1][4] / max(s[-1][1], 1) * 1000 / 2**20:.2f} MiB per 1000 updates)")
        n = 6
        rates = []
        for i in range(n):
            a, b = T * i / n, T * (i + 1) / n
            win = [x for x in s if a <= x[0] <= b]
            if len(win) >= 2 and win[-1][0] > win[0][0]:
                rates.append(f"{(win[-1][1] - win[0][1]) / (win[-1][0] - win[0][0]):.0f}")
            else:
                rates.append("-")
        print(f"updates/s per sixth of the run: {' '.join(rates)}")
        with open(os.path.join(self.dir, "supervisor.log")) as f:
            lines = f.read().splitlines()
        shapes = Counter(re.sub(r"[0-9]+(\.[0-9]+)?", "N", l)[:90] for l in lines)
        print(f"supervisor output: {len(lines)} lines ({len(lines) / max(T / 60, 1e-9):.1f}/min); "
              f"most frequent: {shapes.most_common(1)[0][1] if shapes else 0}x "
              f"'{shapes.most_common(1)[0][0] if shapes else ''}'")
        print(f"exit: {self.exit}; left behind: {self.leftover_shm[0]} /dev/shm files, "
              f"{self.leftover_root} entries under /tmp/p2c-{self.hex}, "
              f"{self.leftover_procs} processes")
        print(f"analyze --verify: {self.verified}")

    def slope(self, kind, T):
        per = defaultdict(list)
        for t, u, procs, *_, workers in self.samples:
            if t < T / 2 or workers != self.args.workers:
                continue
            for pid, (k, rss, *_) in procs.items():
                if k == kind:
                    per[pid].append((u, rss))
        best = max(per.values(), key=lambda v: v[-1][0] - v[0][0] if len(v) > 1 else -1,
                   default=None)
        if not best or len(best) < 3 or best[-1][0] == best[0][0]:
            return None
        n = len(best)
        mu = sum(u for u, _ in best) / n
        mr = sum(r for _, r in best) / n
        den = sum((u - mu) ** 2 for u, _ in best)
        return sum((u - mu) * (r - mr) for u, r in best) / den * 1000 if den else None


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", action="append", help="config (repeatable); "
                    "default: config/A1.toml and config/tball.toml")
    ap.add_argument("--minutes", type=float, default=3.0, help="per config (default 3)")
    ap.add_argument("--workers", type=int, default=3, help="scaled between N and N+3")
    ap.add_argument("--sample-s", type=float, default=2.0, help="sampling interval")
    ap.add_argument("--event-s", type=float, default=10.0,
                    help="interval between scale/set/kill events")
    ap.add_argument("--split-mb", type=int, default=16, help="recording.split_mb")
    ap.add_argument("--keep-parts", type=int, default=8,
                    help="delete finished parts beyond the newest N as the run goes (0: keep all)")
    ap.add_argument("--bin-dir")
    ap.add_argument("--out", default="/tmp/pi2cma-soak")
    ap.add_argument("--run-id", type=lambda s: int(s, 16), default=0x50A4,
                    help="hex; one per config from it on")
    args = ap.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if not args.bin_dir:
        target = os.environ.get("CARGO_TARGET_DIR", os.path.join(root, "target"))
        args.bin_dir = os.path.join(target, "release")
    args.bin_dir = os.path.abspath(args.bin_dir)
    args.out = os.path.abspath(args.out)
    for b in ["supervisor", "updater", "sampler", "rollout-worker", "recorder", "mcap-tool"]:
        if not os.access(os.path.join(args.bin_dir, b), os.X_OK):
            sys.exit(f"{b} not in {args.bin_dir}: cargo build --release -p supervisor -p record")
    configs = args.config or [os.path.join(root, "config/A1.toml"),
                              os.path.join(root, "config/tball.toml")]
    soaks = []
    for i, c in enumerate(configs):
        soak = Soak(args, os.path.abspath(c), args.run_id + i)
        print(f"soaking {c} for {args.minutes} min (run {soak.hex}, files in {soak.dir}) ...",
              flush=True)
        soak.run()
        soaks.append(soak)
    print(f"\nsoak: {time.strftime('%Y-%m-%d')}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f}")
    for s in soaks:
        s.report()


if __name__ == "__main__":
    main()
