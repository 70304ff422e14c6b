#!/usr/bin/env python3
"""Plot the learning curve of a pi2cma run from its MCAP recording.

Reads the file with the PyPI packages `mcap` and `mcap-protobuf-support` only (no pi2cma code):
the protobuf schemas are embedded in the recording. Draws the evaluation cost, the exploration
cost mean ± std band and λ on a log axis, with task changes marked.

    python3 tools/plot_learning_curve.py RUN.mcap [-o curve.svg] [--check] [--log]
    python3 tools/plot_learning_curve.py --join RUN.mcap RUN.part-2.mcap … [-o curve.svg] [--check]

--check decodes every message of every topic and checks the recording's invariants (one
/summary and K /rollout messages per /update, an update index on every message, consecutive
updates, the distribution after one update is the one the next samples from); it exits non-zero
on any failure. A recording without updates (a run that ended before its first: its /run and
/log, or /log alone) passes, as `analyze` reads it. Files whose writer was killed (no summary section) are read as a stream.
Every chunk's CRC is checked: a damaged file (a bad sector, a bad copy) fails, naming the file,
rather than giving other numbers (`pi2cma recover FILE` keeps every undamaged chunk).
A file that is not there, or not MCAP, is named on stderr with what is wrong (exit status 2),
before any file is read.

The cost axis is logarithmic when every cost drawn (exploration mean, evaluation) is positive and
they span more than two decades (a cost falling from 80 to 0.05 is a flat line on a linear axis),
as in `pi2cma analyze`'s learning_curve.svg; --log makes it logarithmic always (a band edge at or
below zero is then cut off). The axis label says "cost (log)".

--join takes the files as one run, in order: the parts of a split recording (`recording.split_mb`)
or a run and the runs resumed from it (`--resume`). It checks that each file goes on exactly where
the one before ends (the next update, sampled from the distribution the last update left) and
draws one learning curve. The part a pipeline recorder restarted after a crash began (metadata
`recorder_restart`, the same `run_id`, the file before as its `previous_part`) goes on from a
later update: the updates the dead recorder had not written are named ("missing 304 (not
recorded: the recorder was restarted)") and left as a gap in the curve, as `analyze` does.
"""

import argparse
import collections
import math
import sys

from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.stream_reader import CRCValidationError
from mcap_protobuf.decoder import DecoderFactory

EXPECTED_TOPICS = {
    "/run": "pi2cma.record.RunInfo",
    "/update": "pi2cma.record.Update",
    "/summary": "pi2cma.record.UpdateSummary",
    "/rollout": "pi2cma.record.Rollout",
    "/task_change": "pi2cma.record.TaskChange",
    "/log": "foxglove.Log",
    "/unfinished_update": "pi2cma.record.UnfinishedUpdate",
}


# What every MCAP file begins with, a killed writer's too: a file without it is no recording.
MAGIC = b"\x89MCAP0\r\n"


def unreadable(path):
    """Why `path` cannot be read as a recording (not there, a directory, not MCAP), or None:
    checked before anything is read, so a wrong argument is one line naming it, not a traceback
    from inside the `mcap` package."""
    try:
        with open(path, "rb") as f:
            head = f.read(len(MAGIC))
    except OSError as e:
        return f"{path}: cannot be read: {e.strerror}"
    if head != MAGIC:
        what = "it is empty" if not head else "it does not begin with the MCAP magic bytes"
        return f"{path}: not an MCAP file ({what})"
    return None


class Damaged(Exception):
    """A chunk whose records fail their CRC: without the check (the `mcap` package's default)
    a flipped byte in a step cost was read as another number, and `--check` passed."""


# The name of the recording's metadata record (run id, part, recorder restart).
METADATA = "pi2cma.run"


def run_metadata(f, indexed):
    """The recording's `pi2cma.run` metadata as a dict (empty if there is none). A killed
    writer's file is read as a stream: the record is written before the first message, so the
    end it lacks is not reached."""
    f.seek(0)
    if indexed:
        records = make_reader(f).iter_metadata()
    else:
        records = NonSeekingReader(f).iter_metadata()
    try:
        for m in records:
            if m.name == METADATA:
                return dict(m.metadata)
    except McapError:
        pass
    return {}


def read(path):
    """Returns {topic: [decoded message, ...]}, whether the file was indexed and its
    `pi2cma.run` metadata; raises Damaged for a chunk that fails its CRC."""
    by_topic = collections.defaultdict(list)
    with open(path, "rb") as f:
        try:
            reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
        except McapError:
            summary = None
        indexed = summary is not None
        meta = run_metadata(f, indexed)
        f.seek(0)
        if indexed:
            reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
            it = reader.iter_decoded_messages(log_time_order=False)
        else:
            f.seek(0)
            reader = NonSeekingReader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
            it = reader.iter_decoded_messages(log_time_order=False)
        try:
            for schema, channel, _message, decoded in it:
                by_topic[channel.topic].append((schema.name, decoded))
        except CRCValidationError as e:
            raise Damaged(
                f"{path}: damaged: {e} (`pi2cma recover {path}` keeps every undamaged chunk)"
            ) from None
        except McapError as e:
            if indexed:
                raise
            print(f"{path}: stream ends early ({e}); using the readable prefix", file=sys.stderr)
    return by_topic, indexed, meta


def check(path, by_topic):
    """Returns a list of failure messages (empty if the recording is consistent)."""
    failures = []

    def fail(msg):
        failures.append(f"{path}: {msg}")

    # A run that ended before its first update (stopped, or a worker that could not start) is a
    # recording too, as `analyze` reads it: its /run and events, its events alone, or its /run
    # alone (a restarted recorder killed right after writing it). Only the topics every update
    # writes are then absent.
    no_updates = "/update" not in by_topic
    optional = {"/task_change", "/unfinished_update"} | ({"/update", "/summary", "/rollout", "/log"} if no_updates else set())
    if no_updates and set(by_topic) <= {"/log"} and by_topic:
        optional.add("/run")
    for topic, schema in EXPECTED_TOPICS.items():
        if topic not in by_topic and topic not in optional:
            fail(f"topic {topic} is missing")
        for name, _ in by_topic.get(topic, []):
            if name != schema:
                fail(f"topic {topic} has schema {name}, expected {schema}")
    for topic, msgs in by_topic.items():
        for i, (_, m) in enumerate(msgs):
            if not m.HasField("timestamp"):
                fail(f"{topic} message {i} has no timestamp")
            if "update" not in m.DESCRIPTOR.fields_by_name:
                fail(f"{topic} message {i} has no update index")
    updates = [m for _, m in by_topic.get("/update", [])]
    summaries = [m for _, m in by_topic.get("/summary", [])]
    rollouts = [m for _, m in by_topic.get("/rollout", [])]
    if not updates:
        # Nothing an update would make may be there without one.
        for topic in ("/summary", "/rollout"):
            if by_topic.get(topic):
                fail(f"{len(by_topic[topic])} {topic} messages but no /update")
        return failures
    if [u.update for u in updates] != list(range(updates[0].update, updates[0].update + len(updates))):
        fail("update indices are not consecutive")
    if [s.update for s in summaries] != [u.update for u in updates]:
        fail("/summary messages do not match /update messages one to one")
    per_update = collections.Counter(r.update for r in rollouts)
    for u in updates:
        k, p, n = u.rollouts, u.dim, u.steps
        # `recording.step_costs = false`: no step costs, each rollout's total in `cost_total`.
        # (`cost_total` is empty in recordings made before it existed.)
        steps = len(u.cost_per_step) == k * n or (not u.cost_per_step and len(u.cost_total) == k)
        if len(u.samples) != k * p or not steps or len(u.cost_terminal) != k:
            fail(f"update {u.update}: shapes K={k} P={p} N={n} do not match the arrays")
        if u.cost_total and len(u.cost_total) != k:
            fail(f"update {u.update}: {len(u.cost_total)} total costs for {k} rollouts")
        if len(u.weights) != k:
            fail(f"update {u.update}: {len(u.weights)} weights for {k} rollouts")
        if per_update.get(u.update, 0) != k:
            fail(f"update {u.update}: {per_update.get(u.update, 0)} /rollout messages, expected {k}")
        total0 = u.cost_terminal[0] + sum(u.cost_per_step[0:n])
        if u.cost_total and u.cost_total[0] != u.eval_cost:
            fail(f"update {u.update}: eval_cost {u.eval_cost} != cost_total[0] {u.cost_total[0]}")
        if u.cost_per_step and not math.isclose(total0, u.eval_cost, rel_tol=1e-12, abs_tol=1e-12):
            fail(f"update {u.update}: eval_cost {u.eval_cost} != total cost of rollout 0 {total0}")
        if list(u.samples[0:p]) != list(u.before.mean):
            fail(f"update {u.update}: rollout 0 is not the mean of the distribution before")
    for a, b in zip(updates, updates[1:]):
        if list(a.after.mean) != list(b.before.mean) or list(a.after.covariance) != list(
            b.before.covariance
        ):
            fail(f"update {b.update}: distribution before is not update {a.update}'s distribution after")
    return failures


def plot(path, by_topic, out, log=False):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summaries = [m for _, m in by_topic.get("/summary", [])]
    run = [m for _, m in by_topic.get("/run", [])]
    changes = [m for _, m in by_topic.get("/task_change", [])]
    # Updates a restarted recorder's predecessor did not write leave a gap in the lines, as in
    # `analyze`'s figure, rather than a line drawn across them.
    x, mean, std, evals, lams = [], [], [], [], []
    for i, s in enumerate(summaries):
        if i and s.update > summaries[i - 1].update + 1:
            for v in (x, mean, std, evals, lams):
                v.append(math.nan)
        x.append(s.update)
        mean.append(s.exploration_cost_mean)
        std.append(s.exploration_cost_std)
        evals.append(s.eval_cost)
        # `lambda` is a Python keyword: the field is read with getattr.
        lams.append(getattr(s, "lambda"))
    fig, (ax, axl) = plt.subplots(2, 1, sharex=True, figsize=(8, 6), height_ratios=[3, 2])
    ax.fill_between(x, [m - s for m, s in zip(mean, std)], [m + s for m, s in zip(mean, std)],
                    alpha=0.25, label="exploration ± std")
    ax.plot(x, mean, label="exploration mean")
    ax.plot(x, evals, label="evaluation (rollout 0)")
    axl.semilogy(x, lams, color="k")
    for c in changes:
        for a in (ax, axl):
            a.axvline(c.update, ls="--", color="grey")
    name = run[0].name if run else path
    ax.set_title(f"{name}: learning curve")
    costs = [c for c in mean + evals if not math.isnan(c)]
    if log or (costs and min(costs) > 0 and max(costs) > 100 * min(costs)):
        ax.set_yscale("log")
        ax.set_ylabel("cost (log)")
    else:
        ax.set_ylabel("cost")
    axl.set_ylabel("λ")
    axl.set_xlabel("update")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def after_restart(prev_path, prev_meta, prev_run, end, meta, run):
    """Whether a file is the part a restarted pipeline recorder began after the recorder of
    `prev_path` died, as `analyze` judges it (record's `is_continued_after_restart_by`):
    metadata `recorder_restart`, the same `run_id`, `prev_path`'s file name as its
    `previous_part`, the same seed, shape and hyperparameters, and a first update at or after
    `end`. The updates between them are missing: the dead recorder had not written them."""
    previous = meta.get("previous_part", "").replace("\\", "/").rsplit("/", 1)[-1]
    return (
        "recorder_restart" in meta
        and meta.get("run_id") is not None
        and meta.get("run_id") == prev_meta.get("run_id")
        and previous == prev_path.replace("\\", "/").rsplit("/", 1)[-1]
        and prev_run is not None
        and run is not None
        and run.update >= end
        and (run.seed, run.dim, run.steps) == (prev_run.seed, prev_run.dim, prev_run.steps)
        # Each file's messages are of classes built from its own embedded schema, which never
        # compare equal: their bytes do.
        and run.hyperparameters.SerializeToString(deterministic=True)
        == prev_run.hyperparameters.SerializeToString(deterministic=True)
    )


def missing_text(first, last):
    return f"{first}" if first == last else f"{first}–{last}"


def join(paths, read_files, metas):
    """Concatenates the files' messages as one run; returns it, the failures of the seams and
    the updates missing at seams where a recorder was restarted."""
    joined = collections.defaultdict(list)
    failures, missing = [], []
    # The last file that held updates, and the file just before (a restarted recorder killed
    # before its first update leaves a part without any; the next restart's part names that
    # part as its `previous_part`, as `analyze` compares it).
    last, last_path, last_meta, last_run = None, None, {}, None
    prev_path, prev_meta, prev_run = None, {}, None
    for path, by_topic, meta in zip(paths, read_files, metas):
        updates = [m for _, m in by_topic.get("/update", [])]
        run = next((m for _, m in by_topic.get("/run", [])), None)
        if last is not None and updates:
            first = updates[0]
            goes_on = first.update == last.update + 1 and list(first.before.mean) == list(
                last.after.mean
            ) and list(first.before.covariance) == list(last.after.covariance)
            if not goes_on and after_restart(prev_path, prev_meta or last_meta, prev_run or last_run,
                                             last.update + 1, meta, run):
                goes_on = True
                if first.update > last.update + 1:
                    missing.append(missing_text(last.update + 1, first.update - 1))
            if not goes_on:
                failures.append(
                    f"{path}: does not go on where {last_path} ends (its first update is "
                    f"{first.update}, {last_path}'s last {last.update})"
                )
        for topic, msgs in by_topic.items():
            joined[topic] += msgs
        if updates:
            last, last_path, last_meta, last_run = updates[-1], path, meta, run
        prev_path, prev_meta, prev_run = path, meta, run
    return joined, failures, missing


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", help="MCAP recordings of pi2cma runs")
    ap.add_argument("-o", "--out", help="figure file (one input or --join) or suffix-free prefix (several)")
    ap.add_argument("--check", action="store_true", help="decode every topic and check invariants")
    ap.add_argument("--log", action="store_true",
                    help="log cost axis (default: log when all costs are positive and span > 2 decades)")
    ap.add_argument("--join", action="store_true", help="the files are one run, in order (parts, resumptions)")
    args = ap.parse_args(argv)
    # Exit status 2, as argparse's for a bad argument: the files named are not recordings.
    wrong = [why for why in map(unreadable, args.files) if why]
    for why in wrong:
        print(f"plot_learning_curve: {why}", file=sys.stderr)
    if wrong:
        return 2
    failures = []
    failed_files = 0
    read_files, metas = [], []
    for i, path in enumerate(args.files):
        try:
            by_topic, indexed, meta = read(path)
        except Damaged as e:
            failures.append(str(e))
            failed_files += 1
            read_files.append({})
            metas.append({})
            continue
        read_files.append(by_topic)
        metas.append(meta)
        counts = ", ".join(f"{t} {len(m)}" for t, m in sorted(by_topic.items()))
        print(f"{path}: {'indexed' if indexed else 'NOT indexed (stream read)'}; decoded {counts}")
        if args.check:
            f = check(path, by_topic)
            failed_files += bool(f)
            failures += f
        if args.join:
            continue
        out = args.out
        if out and len(args.files) > 1:
            # One figure per file: A2.png -> A2-0.png, A2-1.png (the format stays the asked one).
            stem, dot, ext = out.rpartition(".")
            out = f"{stem}-{i}.{ext}" if dot and "/" not in ext else f"{out}-{i}.svg"
        if out:
            plot(path, by_topic, out, args.log)
            print(f"wrote {out}")
    if args.join:
        joined, seams, missing = join(args.files, read_files, metas)
        failures += seams
        updates = [m for _, m in joined.get("/update", [])]
        if seams:
            # Files that do not go on from each other make no learning curve: nothing is drawn.
            print(f"not joined: {len(seams)} of the {len(args.files) - 1} seams do not fit")
        else:
            if updates:
                gaps = (
                    f"; missing {', '.join(missing)} (not recorded: the recorder was restarted)"
                    if missing
                    else ""
                )
                print(f"joined {len(args.files)} files: updates {updates[0].update}..{updates[-1].update}{gaps}")
            if args.out:
                plot(" + ".join(args.files), joined, args.out, args.log)
                print(f"wrote {args.out}")
    for f in failures:
        print(f"FAIL {f}", file=sys.stderr)
    if args.check:
        joined = "" if not args.join else ", join " + ("failed" if seams else "passed")
        print(f"{len(args.files) - failed_files} passed, {failed_files} failed{joined}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
