#!/usr/bin/env bash
# Reproduces the paper's Section IV-A (Fig. 2) in all three weighting modes: 10 sessions of each
# of C1–C3, D, A1–A4. Writes CSVs, figures and tables under runs/, and copies the figures and
# tables the README shows into tools/figures/.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -p pi2cma-cli
configs=(config/C1.toml config/C2.toml config/C3.toml config/D.toml config/A1.toml config/A2.toml config/A3.toml config/A4.toml)
for mode in episodic per-time-step per-time-step-basis-activation; do
  "${CARGO_TARGET_DIR:-target}/release/pi2cma" experiment "${configs[@]}" --sessions 10 --weighting "$mode" --out "runs/viapoint-$mode"
  cp "runs/viapoint-$mode/fig2.svg" "tools/figures/viapoint-$mode.svg"
  cp "runs/viapoint-$mode/summary.md" "tools/figures/viapoint-$mode.md"
done
