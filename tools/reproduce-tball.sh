#!/usr/bin/env bash
# Reproduces the paper's Section IV-B (Fig. 4): 50 sessions of config/tball.toml's T-ball run
# (episodic weighting). Writes CSVs, summary.txt and the figures under runs/tball, and copies
# the figures the README shows into tools/figures/.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -p tball --example tball-experiment
"${CARGO_TARGET_DIR:-target}/release/examples/tball-experiment" --sessions 50 --out runs/tball
for f in cost_lambda ball_trajectories bat_paths; do
  cp "runs/tball/$f.svg" "tools/figures/tball-$f.svg"
done
