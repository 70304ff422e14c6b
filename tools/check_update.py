#!/usr/bin/env python3
"""Independent NumPy re-implementation of the PI²-CMA / PI² / CEM update rule, written from
Stulp & Sigaud, "Path Integral Policy Improvement with Covariance Matrix Adaptation" /
"Adaptive Exploration for Continual Reinforcement Learning" (Algorithm 1, Sections II-A, II-B,
III, III-A, IV-A), NOT from the pi2cma Rust source. It recomputes every update recorded in a
pi2cma MCAP recording and reports the largest differences to what the tool recorded.

    python3 tools/check_update.py RUN.mcap [RUN2.mcap ...] [--per-update] [--sampling] [--json OUT]

What the paper fixes, and how each choice it leaves open is taken here (each marked PAPER or
CHOICE):

* PAPER Alg.1 l.10: θ_k ~ N(θ, Σ), one sample per rollout, constant over the rollout.
  PAPER IV-A: the first of the K trials is the noise-free evaluation trial (θ_0 = θ).
  CHOICE: whether trial 0 enters the update is the recording's `evaluation_in_update`;
  when false, trial 0 gets probability 0 and the others are normalised among themselves.
* PAPER Alg.1 l.17: S_{i,k} = φ_{N,k} + Σ_{j=i}^{N} q_{j,k}. The recording holds q_{0..N-1}
  and φ; S_i is computed for i = 0..N-1.
* PAPER Alg.1 l.18-19: P_{i,k} = E_{i,k}/Σ_l E_{i,l},
  E = exp(-h (S_{i,k} - min_l S_{i,l}) / (max_l S_{i,l} - min_l S_{i,l})).
  CHOICE (the paper's formula is 0/0 there): if max == min, P is uniform.
* PAPER II-A: CEM gives the K_e lowest-cost samples 1/K_e, the others 0.
  CHOICE: ties at the elite boundary are broken by rollout index (stable sort).
* PAPER Alg.1 l.22: δθ_i = Σ_k P_{i,k} (θ_k - θ);  l.27: θ_new = θ + Σ_i (N-i) δθ_i / Σ_i (N-i).
  CHOICE: i runs over the N recorded steps 0..N-1, weights N-i = N..1 (the paper's sum to N
  would add a weight-0 term).
* PAPER Alg.1 l.23: Σ_i = Σ_k P_{i,k} (θ_k - θ)(θ_k - θ)^T  (around the OLD mean, as Eq. 2);
  l.24: Σ_i = boundcovar(Σ_i) (PAPER III-A: eigendecomposition, eigenvalues clipped to
  [λ_min, λ_max], rebuilt from the eigenvectors); l.28: Σ_new = Σ_i (N-i) Σ_i / Σ_i (N-i).
* "Episodic" weighting (PI^BB, not in this paper, exposed by the tool): one P_k from S_{0,k};
  the update is the per-time-step update with the same P at every step.
* "Basis-activation" temporal averaging (original PI², Theodorou 2010, not in this paper):
  parameter j: δθ_j = Σ_i (N-i) ψ_{i,j} δθ_{i,j} / Σ_i (N-i) ψ_{i,j}, ψ from /run
  basis_activations; Σ keeps the (N-i) weights (the README's documented choice).
* PAPER IV-A.1: PI² with constant exploration: Σ unchanged. IV-A.2: λ_u = λ_init D^u, i.e.
  Σ_new = D Σ (CHOICE: Σ ← DΣ, not σ ← Dσ). CEM (Eq. 2): Σ around the old mean with the elite
  probabilities, then bounded if bounds are given (lambda_min 0 and lambda_max inf: no bound).
* Per-dimension covariance (recording's `covariance_block` = B > 0; PAPER: Σ_init = λ_init·I_B
  per DMP dimension, Algorithm 1 written for one dimension): lines 23, 24 and 28 on each
  dimension's B parameters alone, with the probabilities all dimensions share; Σ is
  block-diagonal. 0 (and recordings without the field): one full P×P covariance.
* PAPER IV-A.3 footnote 3: λ_u is the LARGEST eigenvalue of Σ_u.
* PAPER IV-A.1: the learning curve is the cost of trial 0; the band is the standard deviation
  of the K-1 exploration trials (CHOICE: sample std, ddof = 1).
  Compared relative to the costs' size as well as its own: a collapsed Σ makes the std a
  difference of nearly equal totals, whose last bits depend on the order of summation.

Agreement is to rounding, amplified by the problem's conditioning: about 1e-15 relative for
the via-point runs, up to 1e-12 for T-ball (h·|S|/(max S − min S)·ε). The default tolerance,
1e-9, leaves room for that and still catches a wrong rule: a mispaired eigen-decomposition in
boundcovar (nalgebra issue #1109) put Σ off by 4e-6 in one update of a P = 5 run, and this
script found it. `mcap-tool verify` recomputes with the tool's own code and cannot.

The recorded `weights` are compared with the time-averaged probabilities Σ_i T_i P_{i,k}
(T_i = (N-i)/Σ(N-i)); for basis-activation averaging no single per-rollout weight exists and the
comparison is reported separately as 'weights(T-avg)'.
"""

import argparse
import json
import math
import sys

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.stream_reader import CRCValidationError
from mcap_protobuf.decoder import DecoderFactory

MAP_EXP, MAP_ELITES = 1, 2
EXP_CONST, EXP_DECAY, EXP_ADAPT = 1, 2, 3
W_EPI, W_PTS, W_BA = 1, 2, 3


# --------------------------------------------------------------------------- reading
def hp_dict(h):
    return dict(rollouts=h.rollouts, mapping=h.mapping, eliteness=h.eliteness, elites=h.elites,
                exploration=h.exploration, decay=h.decay, lambda_min=h.lambda_min,
                lambda_max=h.lambda_max, weighting=h.weighting,
                evaluation_in_update=h.evaluation_in_update,
                # Absent in recordings made before the field existed: 0, one full covariance.
                covariance_block=getattr(h, "covariance_block", 0))


def dist(d):
    p = d.dim
    return np.array(d.mean, float), np.array(d.covariance, float).reshape(p, p)


# What every MCAP file begins with, a killed writer's too.
MAGIC = b"\x89MCAP0\r\n"


class Unreadable(Exception):
    """A file that cannot be checked (damaged, or not there): `main` names it among the failed
    and goes on with the next file."""

    def __init__(self, what, why):
        super().__init__(why)
        self.what = what


def decoded_messages(path):
    """The file's decoded messages. A file whose writer was killed (no summary section, as
    before `pi2cma recover`) is read as a stream up to where it ends. Every chunk's CRC is
    checked: a damaged file raises `Unreadable` naming it, as the tool's own readers fail, rather
    than being recomputed from other numbers."""
    try:
        f = open(path, "rb")
        head = f.read(len(MAGIC))
    except OSError as e:
        raise Unreadable("cannot be read", f"{path}: cannot be read: {e.strerror}") from e
    with f:
        if head != MAGIC:
            # The `mcap` package fails on such a file with a bare struct.error traceback.
            what = "it is empty" if not head else "it does not begin with the MCAP magic bytes"
            raise Unreadable("not MCAP", f"{path}: not an MCAP file ({what})")
        f.seek(0)
        try:
            reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
            indexed = reader.get_summary() is not None
        except McapError:
            indexed = False
        if not indexed:
            f.seek(0)
            reader = NonSeekingReader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        try:
            yield from reader.iter_decoded_messages(log_time_order=False)
        except CRCValidationError as e:
            raise Unreadable("damaged", f"{path}: damaged: {e} (`pi2cma recover {path}` keeps "
                             f"every undamaged chunk)") from e
        except McapError as e:
            if indexed:
                # A finished file is whole: records that do not read are damage, as for our
                # readers, not a killed writer's end.
                raise Unreadable("damaged", f"{path}: damaged: {e!r} (`pi2cma recover {path}` "
                                 f"keeps every undamaged chunk)") from e
            print(f"{path}: not finished, stream ends early ({e!r}); checking the readable "
                  f"prefix (`pi2cma recover` completes the file)", file=sys.stderr)


def read_recording(path):
    run = None
    updates = []
    changes = []
    for _s, ch, _m, d in decoded_messages(path):
        if ch.topic == "/run":
            run = dict(name=d.name, seed=d.seed, P=d.dim, N=d.steps, hp=hp_dict(d.hyperparameters),
                       initial=dist(d.initial), first_update=d.update,
                       basis=(np.array(d.basis_activations, float).reshape(d.steps, d.dim)
                              if len(d.basis_activations) else None),
                       settings={s.name: s.value for s in d.task_settings})
        elif ch.topic == "/update":
            K, P, N = d.rollouts, d.dim, d.steps
            if not len(d.cost_per_step) and len(d.cost_total) == K:
                # `recording.step_costs = false` (episodic runs only): each rollout's total
                # stands for its trajectory, as zero step costs and the total as terminal cost.
                q, phi = np.zeros((K, N)), np.array(d.cost_total, float)
            else:
                q = np.array(d.cost_per_step, float).reshape(K, N)
                phi = np.array(d.cost_terminal, float)
            updates.append(dict(
                u=d.update, hp=hp_dict(d.hyperparameters), before=dist(d.before), after=dist(d.after),
                samples=np.array(d.samples, float).reshape(K, P),
                q=q,
                phi=phi,
                weights=np.array(d.weights, float),
                eval_cost=d.eval_cost, expl_mean=d.exploration_cost_mean,
                expl_std=d.exploration_cost_std,
                lam=getattr(d, "lambda"), lam_next=d.lambda_next,
                settings={s.name: s.value for s in d.task_settings}))
        elif ch.topic == "/task_change":
            changes.append((d.update, d.name, d.value))
    updates.sort(key=lambda x: x["u"])
    return run, updates, changes


# --------------------------------------------------------------------------- the update rule
def cost_to_go(q, phi):
    """S[k, i] = phi_k + sum_{j>=i} q[k, j]  (Alg. 1 line 17), i = 0..N-1."""
    return phi[:, None] + np.cumsum(q[:, ::-1], axis=1)[:, ::-1]


def probabilities(S, hp, active):
    """S: K x M costs (M = N steps, or 1 for episodic). Returns P: K x M, columns sum to 1 over
    the active rollouts; inactive rollouts get 0."""
    K, M = S.shape
    P = np.zeros((K, M))
    Sa = S[active]
    if hp["mapping"] == MAP_EXP:
        h = hp["eliteness"]
        mn = Sa.min(axis=0)
        mx = Sa.max(axis=0)
        rng = mx - mn
        E = np.ones_like(Sa)
        ok = rng > 0
        E[:, ok] = np.exp(-h * (Sa[:, ok] - mn[ok]) / rng[ok])
        P[active] = E / E.sum(axis=0)
    elif hp["mapping"] == MAP_ELITES:
        ke = hp["elites"]
        idx = np.flatnonzero(active)
        order = np.argsort(Sa, axis=0, kind="stable")[:ke]  # ke x M
        for m in range(M):
            P[idx[order[:, m]], m] = 1.0 / ke
    else:
        raise ValueError(f"unknown mapping {hp['mapping']}")
    return P


def boundcovar(C, lo, hi):
    """Clip the eigenvalues of symmetric C (..., P, P) to [lo, hi] (Sec. III-A)."""
    w, V = np.linalg.eigh(C)
    w = np.clip(w, lo, hi)
    return np.einsum("...ab,...b,...cb->...ac", V, w, V)


def update(before_mean, before_cov, samples, q, phi, hp, basis=None):
    K, P = samples.shape
    N = q.shape[1]
    active = np.ones(K, bool)
    if not hp["evaluation_in_update"]:
        active[0] = False
    S = cost_to_go(q, phi)  # K x N
    episodic = hp["weighting"] == W_EPI
    Pm = probabilities(S[:, :1] if episodic else S, hp, active)  # K x M
    M = Pm.shape[1]
    T = (N - np.arange(N)).astype(float)
    T /= T.sum()
    eps = samples - before_mean  # K x P
    if episodic:
        w_avg = Pm[:, 0]
        dtheta = w_avg @ eps
        new_mean = before_mean + dtheta
    else:
        dth_i = Pm.T @ eps  # N x P: δθ_i = Σ_k P_ik (θ_k - θ)  (line 22)
        w_avg = Pm @ T
        if hp["weighting"] == W_PTS:
            new_mean = before_mean + T @ dth_i  # line 27
        elif hp["weighting"] == W_BA:
            if basis is None:
                raise ValueError("basis-activation averaging needs /run basis_activations")
            Wt = (N - np.arange(N))[:, None] * basis  # N x P
            new_mean = before_mean + (Wt * dth_i).sum(0) / Wt.sum(0)
        else:
            raise ValueError(f"unknown weighting {hp['weighting']}")
    ex = hp["exploration"]
    if ex == EXP_CONST:
        new_cov = before_cov.copy()
    elif ex == EXP_DECAY:
        new_cov = hp["decay"] * before_cov
    elif ex == EXP_ADAPT and hp["covariance_block"] > 0:
        # Per DMP dimension: each B x B block is lines 23-24 and 28 on that dimension's
        # parameters alone, with the probabilities all dimensions share; zero across blocks.
        B = hp["covariance_block"]
        if P % B:
            raise ValueError(f"covariance_block = {B} does not divide P = {P}")
        new_cov = np.zeros((P, P))
        for d in range(P // B):
            blk = slice(d * B, (d + 1) * B)
            new_cov[blk, blk] = adapted_covariance(eps[:, blk], Pm, T, hp, episodic)
    elif ex == EXP_ADAPT:
        new_cov = adapted_covariance(eps, Pm, T, hp, episodic)
    else:
        raise ValueError(f"unknown exploration {ex}")
    tot = S[:, 0]
    B = hp["covariance_block"] or P
    return dict(weights=w_avg, mean=new_mean, cov=new_cov,
                lam=largest_eigenvalue(before_cov, B),
                lam_next=largest_eigenvalue(new_cov, B),
                eval_cost=float(tot[0]), expl_mean=float(tot[1:].mean()),
                expl_std=float(tot[1:].std(ddof=1)), total=tot, S=S, P=Pm)


def largest_eigenvalue(C, B):
    """λ (PAPER IV-A.3 footnote 3): the largest eigenvalue of Σ; with per-dimension blocks of
    size B, the largest over the blocks (the same matrix's eigenvalues, found block by block)."""
    P = C.shape[0]
    return float(max(np.linalg.eigvalsh(C[d * B:(d + 1) * B, d * B:(d + 1) * B]).max()
                     for d in range(P // B)))


def adapted_covariance(eps, Pm, T, hp, episodic):
    """Lines 23, 24 and 28 for the parameters whose ε are the columns of `eps`."""
    lo, hi = hp["lambda_min"], hp["lambda_max"]
    if episodic:
        C = np.einsum("k,ka,kb->ab", Pm[:, 0], eps, eps)  # line 23 / Eq. 2
        new_cov = boundcovar(C, lo, hi)  # line 24
    else:
        # group identical probability columns (often many steps share them) for speed
        cols, inv = np.unique(Pm.T, axis=0, return_inverse=True)
        inv = np.asarray(inv).reshape(-1)
        Cu = np.einsum("mk,ka,kb->mab", cols, eps, eps)
        Cu = boundcovar(Cu, lo, hi)
        Tu = np.bincount(inv, weights=T, minlength=len(cols))
        new_cov = np.einsum("m,mab->ab", Tu, Cu)  # line 28
    return new_cov


# --------------------------------------------------------------------------- comparison
def reldiff(a, b):
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    if a.shape != b.shape:
        return float("inf")
    scale = max(np.abs(b).max(), np.abs(a).max(), 1e-300)
    return float(np.abs(a - b).max() / scale)


def std_diff(a, b, totals):
    """The difference of two standard deviations of the exploration costs, relative to the
    larger of them and of the costs themselves. The totals carry rounding of their own sums
    (ours add the steps in another order), about ε·|cost|, and so does their spread: once the
    costs agree to 13 digits (an unbounded CEM whose Σ has collapsed), their std differs in its
    leading digits between two correct summations, and relative to itself it said DISAGREES."""
    scale = max(abs(a), abs(b), float(np.abs(totals).max()), 1e-300)
    return float(abs(a - b) / scale)


QUANTS = ["weights", "mean", "cov", "lam", "lam_next", "eval_cost", "expl_mean", "expl_std"]


def check_file(path, per_update=False):
    run, ups, changes = read_recording(path)
    res = {q: (0.0, None) for q in QUANTS}
    invariants = []
    prev_after = None
    for up in ups:
        m0, c0 = up["before"]
        r = update(m0, c0, up["samples"], up["q"], up["phi"], up["hp"], run["basis"])
        d = dict(weights=reldiff(r["weights"], up["weights"]), mean=reldiff(r["mean"], up["after"][0]),
                 cov=reldiff(r["cov"], up["after"][1]), lam=reldiff(r["lam"], up["lam"]),
                 lam_next=reldiff(r["lam_next"], up["lam_next"]),
                 eval_cost=reldiff(r["eval_cost"], up["eval_cost"]),
                 expl_mean=reldiff(r["expl_mean"], up["expl_mean"]),
                 expl_std=std_diff(r["expl_std"], up["expl_std"], r["total"]))
        for q in QUANTS:
            if d[q] > res[q][0] or res[q][1] is None:
                res[q] = (max(d[q], res[q][0]), up["u"] if d[q] >= res[q][0] else res[q][1])
        if per_update:
            print(f"  u={up['u']:3d} " + " ".join(f"{q}={d[q]:.1e}" for q in QUANTS))
        # invariants
        if not np.array_equal(up["samples"][0], m0):
            invariants.append(f"u={up['u']}: rollout 0 is not the mean")
        if prev_after is not None and not (np.array_equal(prev_after[0], m0) and np.array_equal(prev_after[1], c0)):
            invariants.append(f"u={up['u']}: before != previous after")
        if not np.allclose(up["after"][1], up["after"][1].T, rtol=0, atol=0):
            invariants.append(f"u={up['u']}: Σ_after not exactly symmetric")
        ev = np.linalg.eigvalsh(up["after"][1])
        hp = up["hp"]
        if hp["exploration"] == EXP_ADAPT:
            lo, hi = hp["lambda_min"], hp["lambda_max"]
            tol = 1e-12 * max(abs(ev).max(), 1e-300)  # rounding of a rank-deficient Σ
            if ev.min() < lo * (1 - 1e-9) - tol or ev.max() > hi * (1 + 1e-9) + tol:
                invariants.append(f"u={up['u']}: eigenvalues {ev} outside [{lo},{hi}]")
        if ev.min() < -1e-12 * max(abs(ev).max(), 1e-300):
            invariants.append(f"u={up['u']}: Σ_after indefinite {ev}")
        prev_after = up["after"]
    return run, ups, changes, res, invariants


def sampling_check(ups):
    """Whiten θ_k - θ (k >= 1) with the Cholesky factor of the before-Σ; pool all updates."""
    Z = []
    for up in ups:
        m0, c0 = up["before"]
        L = np.linalg.cholesky(c0)
        Z.append(np.linalg.solve(L, (up["samples"][1:] - m0).T).T)
    Z = np.vstack(Z)
    n, p = Z.shape
    z = Z.reshape(-1)
    zs = np.sort(z)
    cdf = 0.5 * (1 + np.vectorize(math.erf)(zs / math.sqrt(2)))
    ks = max(np.max(np.arange(1, len(zs) + 1) / len(zs) - cdf), np.max(cdf - np.arange(len(zs)) / len(zs)))
    cov = np.cov(Z.T) if p > 1 else np.array([[Z.var(ddof=1)]])
    return dict(n=n, p=p, mean_abs_max=float(np.abs(Z.mean(0)).max()),
                mean_se=1 / math.sqrt(n), cov_offdiag_max=float(np.abs(cov - np.diag(np.diag(cov))).max()),
                var_min=float(np.diag(cov).min()), var_max=float(np.diag(cov).max()),
                kurtosis=float((z ** 4).mean() / (z ** 2).mean() ** 2), ks=float(ks),
                ks_crit_1pct=1.63 / math.sqrt(len(z)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--per-update", action="store_true")
    ap.add_argument("--sampling", action="store_true", help="also test θ_k - θ ~ N(0, Σ)")
    ap.add_argument("--json", help="write the results as JSON")
    ap.add_argument("--tol", type=float, default=1e-9, help="largest relative difference accepted")
    a = ap.parse_args()
    out = {}
    bad = False
    empty = 0
    total = 0
    # Every file is checked, whichever failed before it; each failed one is named at the end.
    failed = []
    unreadable = 0
    for path in a.files:
        try:
            run, ups, changes, res, inv = check_file(path, a.per_update)
        except Unreadable as e:
            print(f"check_update: {e}", file=sys.stderr)
            failed.append(f"{path} ({e.what})")
            unreadable += 1
            out[path] = dict(error=str(e))
            continue
        if run is None or not ups:
            # A run that ended before its first update (its /run and /log, or /log alone): there
            # is nothing to recompute, which is no agreement (it failed with a TypeError on a
            # file without /run, and said "DISAGREES" of one with it).
            print(f"{path}\n  no update recorded{'' if run else ' (nor a /run)'}: nothing to recompute")
            empty += 1
            failed.append(f"{path} (no update recorded)")
            out[path] = dict(run=run and run["name"], updates=0)
            continue
        hp = run["hp"]
        label = (f"{run['name']}: K={hp['rollouts']} P={run['P']} N={run['N']} mapping={hp['mapping']} "
                 f"expl={hp['exploration']} weighting={hp['weighting']} eval_in_update={hp['evaluation_in_update']} "
                 f"λ∈[{hp['lambda_min']},{hp['lambda_max']}] "
                 + (f"Σ per dimension ({hp['covariance_block']}×{hp['covariance_block']} blocks) "
                    if hp["covariance_block"] else "")
                 + f"updates={len(ups)} changes={changes}")
        print(f"{path}\n  {label}")
        print("  max rel diff: " + "  ".join(f"{q}={res[q][0]:.2e}(u{res[q][1]})" for q in QUANTS))
        worst = max(res[q][0] for q in QUANTS)
        # `not <=`: a NaN difference fails too.
        disagrees = not worst <= a.tol or any(math.isnan(res[q][0]) for q in QUANTS)
        if disagrees:
            print(f"  >>> DISAGREES beyond {a.tol:g}")
        for s in inv[:10]:
            print("  invariant broken:", s)
        why = ([f"disagrees beyond {a.tol:g}"] if disagrees else []) + (
            [f"{len(inv)} invariant(s) broken"] if inv else [])
        if why:
            bad = True
            failed.append(f"{path} ({', '.join(why)})")
        total += len(ups)
        entry = dict(run=run["name"], updates=len(ups), maxrel={q: res[q][0] for q in QUANTS},
                     at={q: res[q][1] for q in QUANTS}, invariants=inv)
        if a.sampling:
            sc = sampling_check(ups)
            entry["sampling"] = sc
            print("  sampling:", {k: (round(v, 4) if isinstance(v, float) else v) for k, v in sc.items()})
        out[path] = entry
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1)
    verdict = ["DISAGREES" if bad else f"agrees within {a.tol:g}"] if total else []
    if empty:
        verdict.append(f"{empty} recording(s) without an update to recompute")
    if unreadable:
        verdict.append(f"{unreadable} recording(s) not checked")
    print(f"check_update: {len(a.files)} recording(s), {total} updates: {'; '.join(verdict)}")
    if failed:
        print(f"check_update: failed: {', '.join(failed)}")
    sys.exit(1 if failed or empty else 0)


if __name__ == "__main__":
    main()
