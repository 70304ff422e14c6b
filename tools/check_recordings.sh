#!/usr/bin/env bash
# Proof that recordings are readable by tools other than ours: records an in-process run, a
# pipeline run (recorder process + supervisor) and an in-process run killed with SIGKILL, and has
# tools/plot_learning_curve.py (PyPI `mcap` + `mcap-protobuf-support` only) decode every topic of
# each and check its invariants; the killed file is checked as written (streaming read, also by
# tools/check_update.py) and after `mcap-tool recover`. Then recomputes every update of these and of runs of every update-rule
# variant with tools/check_update.py, a NumPy implementation written from the paper. Exits
# non-zero on any failure.
#
# Needs: python3 with tools/requirements.txt installed, cargo. Run from anywhere; --release uses
# the release binaries.
set -Eeuo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
target="${CARGO_TARGET_DIR:-$root/target}"
# --release: use (and build if needed) the release binaries, e.g. after `cargo test --release`.
profile=debug
flags=()
if [ "${1:-}" = "--release" ]; then
  profile=release
  flags=(--release)
fi
cargo build --quiet "${flags[@]}" -p record --bins
# The supervisor's process binaries, the recorder among them.
cargo build --quiet "${flags[@]}" -p supervisor --bins
cargo build --quiet "${flags[@]}" -p pi2cma-cli --bins
bin="$target/$profile"
work="$(mktemp -d)"
# Background processes too: a recorder left waiting by a failed stage held the output pipe open,
# and a CI log piped through it never ended. (A bare `kill` with no jobs left fails, and the ERR
# trap then reported a failure after the last line of a passing run.)
trap 'for job in $(jobs -p); do kill "$job" 2>/dev/null || true; done; rm -rf "$work"' EXIT
# The last line counts the checks that ran: each stage is added when it has passed, and a failing
# command (set -e) reports the stage it was in.
passed=()
stage=""
begin() { stage="$1"; echo "== $1"; }
done_stage() { passed+=("$stage"); }
failed() { echo "recordings: ${#passed[@]} passed, 1 failed (${stage})" >&2; }
# Only in this shell: set -E hands the trap to command substitutions too, whose failure then
# printed the line twice (once there, once for the assignment that failed with it).
trap '[ "$BASHPID" = "$$" ] && failed' ERR

begin "in-process run"
"$bin/mcap-tool" record --out "$work/in-process.mcap"
python3 tools/plot_learning_curve.py --check "$work/in-process.mcap" -o "$work/in-process.png"

done_stage

begin "pipeline run with the recorder process"
run_id="$(printf '%08x%08x' $$ 4242)"
sed 's/^viapoint_weight = 1000.0$/viapoint_weight = 1000.0\nrollout_delay_ms = 1.0/' \
  crates/session/src/default.toml > "$work/pipeline.toml"
"$bin/recorder" --config "$work/pipeline.toml" --run-dir "$work" --run-id "$run_id" \
  --out "$work/pipeline.mcap" &
recorder=$!
for _ in $(seq 100); do [ -f "$work/pipeline.mcap" ] && break; sleep 0.1; done
sleep 0.3
# --no-record: the recorder started above is the one under test (the services have room for one).
PI2CMA_RUN_DIR="$work/runs" timeout 120 "$bin/supervisor" run "$work/pipeline.toml" \
  --run-id "$run_id" --bin-dir "$bin" --quiet --no-record
wait "$recorder"
python3 tools/plot_learning_curve.py --check "$work/pipeline.mcap" -o "$work/pipeline.png"

done_stage

begin "in-process run killed with SIGKILL, then recovered"
"$bin/mcap-tool" record --progress --updates 100000 --rollout-delay-ms 1 \
  --out "$work/killed.mcap" > "$work/progress.txt" 2>/dev/null &
writer=$!
for _ in $(seq 200); do
  [ "$(grep -c . "$work/progress.txt" || true)" -ge 5 ] && break
  sleep 0.05
done
kill -9 "$writer"
wait "$writer" 2>/dev/null || true
flushed="$(tail -1 "$work/progress.txt" | awk '{print $3}')"
python3 tools/plot_learning_curve.py --check "$work/killed.mcap"
python3 tools/check_update.py "$work/killed.mcap"
"$bin/mcap-tool" recover "$work/killed.mcap"
python3 tools/plot_learning_curve.py --check "$work/killed.mcap"
"$bin/mcap-tool" verify "$work/killed.mcap"
recorded="$("$bin/mcap-tool" info "$work/killed.mcap" | sed -n 's/^  updates: \([0-9]*\) .*/\1/p')"
# A figure that is not a number (a changed output format) fails too: `[ "" -le 3 ]` is an
# error that `if` takes for false, and the check passed unseen.
if ! [[ "$flushed" =~ ^[0-9]+$ && "$recorded" =~ ^[0-9]+$ ]]; then
  echo "FAIL: an update number that is not one: flushed '$flushed' (the progress's last line), \
recovered '$recorded' (mcap-tool info)" >&2
  failed
  exit 1
fi
if [ "$recorded" -le "$flushed" ]; then
  echo "FAIL: update $flushed was reported flushed but only $recorded updates were recovered" >&2
  failed
  exit 1
fi
done_stage
begin "the update rule of every variant, recomputed by an independent NumPy implementation"
# tools/check_update.py is written from the paper, not from our code: it catches what `mcap-tool
# verify` (our code recomputing itself) cannot. Each variant is a config of config/ changed by
# sed; together they reach every kernel of the update (P = 2 closed form, 3 ≤ P ≤ m dense,
# P > m low rank; episodic, per time step, basis activation; CEM, PI² constant and decaying).
variant() { # name, base config, sed expressions (each one must change the config)
  local name="$1" base="config/$2.toml" edits=(-e "s/^name = .*/name = \"$1\"/")
  shift 2
  # An expression that matches no line left the variant its base config: the kernel it was
  # for went unchecked, and the stage passed all the same.
  for e in "$@"; do
    if sed -e "$e" "$base" | cmp -s - "$base"; then
      echo "FAIL: variant $name: \`$e\` changes nothing in $base" >&2
      failed
      exit 1
    fi
    edits+=(-e "$e")
  done
  sed "${edits[@]}" "$base" > "$work/$name.toml"
  "$bin/pi2cma" run "$work/$name.toml" --out "$work/$name" --quiet > /dev/null
  checked+=("$work/$name/run.mcap")
}
checked=("$work/in-process.mcap" "$work/pipeline.mcap" "$work/killed.mcap")
variant A1 A1
variant A1-p5-per-step A1 's/^weighting = .*/weighting = "per-time-step"/' 's/^basis_functions = 2/basis_functions = 5/'
variant A1-p20-basis A1 's/^weighting = .*/weighting = "per-time-step"\ntemporal_averaging = "basis-activation"/' \
  's/^basis_functions = 2/basis_functions = 20/'
variant CEM-per-step A1 's/^method = .*/method = "cem"/' 's/^weighting = .*/weighting = "per-time-step"/' \
  's/^eliteness = .*/elites = 5/'
variant C2 C2
variant D-per-step D 's/^weighting = .*/weighting = "per-time-step"/'
variant tball tball
# One B×B covariance per joint (optimizer.covariance): 7 blocks of 3, episodic and per time step.
variant tball-per-dimension tball 's/^\[optimizer\]$/[optimizer]\ncovariance = "per-dimension"/'
variant tball-per-dimension-per-step tball 's/^\[optimizer\]$/[optimizer]\ncovariance = "per-dimension"/' \
  's/^weighting = .*/weighting = "per-time-step"/'
"$bin/mcap-tool" verify "$work/tball-per-dimension-per-step/run.mcap"
python3 tools/check_update.py "${checked[@]}"
done_stage
begin "the DMP and task costs of every variant, recomputed by an independent NumPy implementation"
# check_update.py takes the samples' costs from the recording: a wrong DMP or cost function
# would pass it. tools/check_task_costs.py rebuilds both from the paper and the README.
python3 tools/check_task_costs.py "${checked[@]}"
done_stage

echo "recordings: ${#passed[@]} passed, 0 failed"
