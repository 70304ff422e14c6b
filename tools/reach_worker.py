#!/usr/bin/env python3
"""The reach task of crates/supervisor/examples/reach-worker.rs, as a Python user would write it:
a planar two-link arm whose hand should pass through a target halfway through a 1 s reach. The
policy is the user's own, not a DMP: a minimum-jerk joint trajectory plus 5 Gaussian bumps per
joint (θ: their heights in radians), so P = 10, N = 101. config/external-reach-python.toml runs
it:

    cargo run --release -p supervisor -- run config/external-reach-python.toml

Replace `rollout` with a call into your simulator or your robot.
"""

import math
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import pi2cma_worker  # noqa: E402

START = (0.3, 1.6)
END = (1.4, 0.5)
LINKS = (0.5, 0.4)
BUMPS = 5
DT = 0.01
STEPS = 101
TARGET_WEIGHT = 1e4


class Reach:
    parameters = 2 * BUMPS
    steps = STEPS

    def __init__(self, shape):
        self.settings = {"target_x": math.nan, "target_y": math.nan}
        t = [i * DT for i in range(STEPS)]
        s = [ti / t[-1] for ti in t]
        self.min_jerk = [
            [a + (b - a) * (10 * x**3 - 15 * x**4 + 6 * x**5) for x in s] for a, b in zip(START, END)
        ]
        # Bumps vanish at both ends (sin² window), so the reach starts and ends where it should.
        centers = [(b + 1) / (BUMPS + 1) for b in range(BUMPS)]
        self.basis = [
            [math.exp(-((x - c) ** 2) / (2 * 0.1**2)) * math.sin(math.pi * x) ** 2 for x in s]
            for c in centers
        ]

    def set(self, name, value):
        if name not in self.settings:
            raise ValueError(f"the reach task has no setting {name!r}")
        # A target the arm cannot reach is refused: the pipeline then runs the update with the
        # target it had, and the run goes on.
        target = dict(self.settings, **{name: value})
        distance = math.hypot(target["target_x"], target["target_y"])
        if distance > sum(LINKS):
            raise ValueError(
                f"target ({target['target_x']}, {target['target_y']}) is {distance:.2f} m from the "
                f"shoulder, out of the arm's reach ({sum(LINKS)} m)"
            )
        self.settings[name] = value

    def rollout(self, theta):
        q = [
            [
                self.min_jerk[d][i] + sum(theta[d * BUMPS + b] * self.basis[b][i] for b in range(BUMPS))
                for i in range(STEPS)
            ]
            for d in range(2)
        ]
        costs = []
        for i in range(STEPS):
            acc2 = 0.0
            for d in range(2):
                lo, hi = max(i - 1, 0), min(i + 1, STEPS - 1)
                a = (q[d][hi] - 2 * q[d][i] + q[d][lo]) / DT**2 if 0 < i < STEPS - 1 else 0.0
                acc2 += a * a
            costs.append(1e-3 * acc2 / STEPS)
        mid = (STEPS - 1) // 2
        q1, q2 = q[0][mid], q[1][mid]
        x = LINKS[0] * math.cos(q1) + LINKS[1] * math.cos(q1 + q2)
        y = LINKS[0] * math.sin(q1) + LINKS[1] * math.sin(q1 + q2)
        costs[mid] += TARGET_WEIGHT * ((x - self.settings["target_x"]) ** 2 + (y - self.settings["target_y"]) ** 2)
        return costs, 0.0


if __name__ == "__main__":
    pi2cma_worker.serve(Reach)
