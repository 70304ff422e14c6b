//! Eigen-decomposition of small symmetric matrices for the per-time-step low-rank kernel, which
//! needs one K×K eigenproblem per time step (1,000 per update for a large policy). Besides the
//! full decomposition, the pieces of a partial one: the tridiagonal reduction alone, Sturm
//! counts, bisection and inverse iteration for selected eigenpairs. Householder
//! tridiagonalisation and the implicit QL algorithm (EISPACK tred2/tql2, as in JAMA), written
//! over column-major slices so that the hot loops — the rotations accumulated into the
//! eigenvectors — run over contiguous memory and vectorise; compiled for AVX2 too and chosen at
//! run time. About twice as fast as nalgebra's general `SymmetricEigen` at K = 50.

/// Decomposes the symmetric n×n matrix in `v` (column-major; only its values are read, both
/// triangles must be set). On return `v` holds the orthonormal eigenvectors as columns and `d`
/// the eigenvalues (unsorted). `e` is n values of scratch.
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
pub fn symmetric_eigen(n: usize, v: &mut [f64], d: &mut [f64], e: &mut [f64]) {
    assert!(v.len() == n * n && d.len() == n && e.len() == n);
    if n == 0 {
        return;
    }
    let unscale = scale_towards_one(v);
    reduce(n, v, d, e);
    accumulate(n, v, d, e);
    ql::<true>(n, v, d, e);
    if let Some(unscale) = unscale {
        d.iter_mut().for_each(|x| *x *= unscale);
    }
}

/// The largest eigenvalue of the symmetric n×n matrix in `v` (column-major, both triangles
/// set; overwritten): [`symmetric_eigen`]'s, so the same bits, without the eigenvectors, which
/// are most of its work. `scratch`: 3·n values.
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
pub fn largest_eigenvalue(n: usize, v: &mut [f64], scratch: &mut [f64]) -> f64 {
    assert!(v.len() == n * n && scratch.len() == 3 * n);
    if n == 0 {
        return 0.0;
    }
    let unscale = scale_towards_one(v);
    let (d, rest) = scratch.split_at_mut(n);
    let (e, h) = rest.split_at_mut(n);
    reduce(n, v, h, e);
    // As `accumulate` leaves them for QL: the diagonal, and the off-diagonal from e[1].
    e[0] = 0.0;
    for (i, di) in d.iter_mut().enumerate() {
        *di = v[i * n + i];
    }
    ql::<false>(n, &mut [], d, e);
    let largest = d.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    largest * unscale.unwrap_or(1.0)
}

/// Products of two entries (QL's e_l·e_(l+1), the squares in its rotations) leave f64's range
/// for a matrix far from 1 in size, and the eigenvalues came out 0 or NaN. Such a matrix is
/// scaled by a power of 2 towards 1 first, as LAPACK's dsteqr does; a power of 2 scales every
/// step of the algorithm exactly, so the eigenvectors are those of the matrix and the
/// eigenvalues scale back exactly. Other matrices are left as they are. Returns what to
/// multiply the eigenvalues by, if `v` was scaled.
#[inline(always)]
fn scale_towards_one(v: &mut [f64]) -> Option<f64> {
    let unscale = unscale_for(v.iter().fold(0.0f64, |m, x| m.max(x.abs())));
    if let Some(unscale) = unscale {
        let scale = 1.0 / unscale;
        v.iter_mut().for_each(|x| *x *= scale);
    }
    unscale
}

/// For a symmetric matrix whose largest |entry| is `amax`: the power of 2 to divide it by
/// before an eigen-decomposition (and to multiply the eigenvalues by after), or `None` if
/// `amax` is within 2^±240, where the square of an entry and its product with f64::EPSILON stay
/// far inside f64's normal range and the matrix is decomposed as it is. A power of 2 scales
/// every step of the algorithms exactly.
pub(crate) fn unscale_for(amax: f64) -> Option<f64> {
    const SAFE_MIN: f64 = 1.0 / (1u128 << 120) as f64 / (1u128 << 120) as f64;
    if !(amax.is_finite() && amax > 0.0) || (SAFE_MIN..=1.0 / SAFE_MIN).contains(&amax) {
        return None;
    }
    Some(2f64.powi((amax.log2().floor() as i32).clamp(-1022, 1023)))
}

/// Householder reduction of the symmetric matrix in `v` to tridiagonal form (tred2's first
/// half). Afterwards the tridiagonal's diagonal is v's diagonal, `e[s]` (s ≥ 1) couples rows
/// s − 1 and s (`e[0]` is garbage), and the reflector of step s (s = n − 1 down to 1) is
/// I − u·uᵀ/h with u in rows 0..s of column s of `v` and h = `d[s]` (0: no reflection).
#[inline(always)]
fn reduce(n: usize, v: &mut [f64], d: &mut [f64], e: &mut [f64]) {
    // v[j*n + k] is V[k][j] of the textbook formulation.
    let at = |k: usize, j: usize| j * n + k;
    for j in 0..n {
        d[j] = v[at(n - 1, j)];
    }

    // Householder reduction to tridiagonal form.
    for i in (1..n).rev() {
        let mut scale = 0.0;
        let mut h = 0.0;
        for dk in &d[..i] {
            scale += dk.abs();
        }
        if scale == 0.0 {
            e[i] = d[i - 1];
            for j in 0..i {
                d[j] = v[at(i - 1, j)];
                v[at(i, j)] = 0.0;
                v[at(j, i)] = 0.0;
            }
        } else {
            for dk in &mut d[..i] {
                *dk /= scale;
                h += *dk * *dk;
            }
            let mut f = d[i - 1];
            let mut g = h.sqrt();
            if f > 0.0 {
                g = -g;
            }
            e[i] = scale * g;
            h -= f * g;
            d[i - 1] = f - g;
            e[..i].fill(0.0);
            for j in 0..i {
                f = d[j];
                v[at(j, i)] = f;
                let col = &v[j * n..j * n + i];
                g = e[j] + col[j] * f + dot(&col[j + 1..i], &d[j + 1..i]);
                for (ek, ck) in e[j + 1..i].iter_mut().zip(&col[j + 1..i]) {
                    *ek += ck * f;
                }
                e[j] = g;
            }
            f = 0.0;
            for j in 0..i {
                e[j] /= h;
                f += e[j] * d[j];
            }
            let hh = f / (h + h);
            for j in 0..i {
                e[j] -= hh * d[j];
            }
            for j in 0..i {
                let (f, g) = (d[j], e[j]);
                let col = &mut v[j * n..j * n + i];
                for k in j..i {
                    col[k] -= f * e[k] + g * d[k];
                }
                d[j] = v[at(i - 1, j)];
                v[at(i, j)] = 0.0;
            }
        }
        d[i] = h;
    }
}

/// Turns the output of [`reduce`] into the orthogonal Q (columns, in `v`) with A = Q·T·Qᵀ, the
/// tridiagonal's diagonal in `d` and its off-diagonal in `e[1..]` (`e[0]` = 0).
#[inline(always)]
fn accumulate(n: usize, v: &mut [f64], d: &mut [f64], e: &mut [f64]) {
    let at = |k: usize, j: usize| j * n + k;
    for i in 0..n - 1 {
        v[at(n - 1, i)] = v[at(i, i)];
        v[at(i, i)] = 1.0;
        let h = d[i + 1];
        if h != 0.0 {
            for k in 0..=i {
                d[k] = v[at(k, i + 1)] / h;
            }
            for j in 0..i + 1 {
                let (cj, ci1) = column_pair(v, n, j, i + 1);
                let g = dot(&ci1[..i + 1], &cj[..i + 1]);
                for (c, dk) in cj[..i + 1].iter_mut().zip(&d[..i + 1]) {
                    *c -= g * dk;
                }
            }
        }
        for k in 0..=i {
            v[at(k, i + 1)] = 0.0;
        }
    }
    for j in 0..n {
        d[j] = v[at(n - 1, j)];
        v[at(n - 1, j)] = 0.0;
    }
    v[at(n - 1, n - 1)] = 1.0;
    e[0] = 0.0;
}

/// Implicit QL on the tridiagonal matrix (diagonal `d`, off-diagonal `e[1..]`): the eigenvalues
/// into `d`; with `VECTORS`, the rotations are also applied to the columns of `v`. The
/// eigenvalues do not depend on `VECTORS`: the rotations of `v` never feed back into (d, e).
#[inline(always)]
fn ql<const VECTORS: bool>(n: usize, v: &mut [f64], d: &mut [f64], e: &mut [f64]) {
    for i in 1..n {
        e[i - 1] = e[i];
    }
    e[n - 1] = 0.0;
    let mut f = 0.0;
    let mut tst1: f64 = 0.0;
    let eps = f64::EPSILON;
    for l in 0..n {
        tst1 = tst1.max(d[l].abs() + e[l].abs());
        let mut m = l;
        while m < n - 1 && e[m].abs() > eps * tst1 {
            m += 1;
        }
        if m > l {
            // A bound on the iterations keeps a NaN input from looping forever.
            for _ in 0..100 {
                let mut g = d[l];
                let mut p = (d[l + 1] - g) / (2.0 * e[l]);
                let mut r = hypot(p, 1.0);
                if p < 0.0 {
                    r = -r;
                }
                d[l] = e[l] / (p + r);
                d[l + 1] = e[l] * (p + r);
                let dl1 = d[l + 1];
                let mut h = g - d[l];
                for di in &mut d[l + 2..] {
                    *di -= h;
                }
                f += h;
                p = d[m];
                let (mut c, mut c2, mut c3) = (1.0, 1.0, 1.0);
                let el1 = e[l + 1];
                let (mut s, mut s2) = (0.0, 0.0);
                for i in (l..m).rev() {
                    c3 = c2;
                    c2 = c;
                    s2 = s;
                    g = c * e[i];
                    h = c * p;
                    r = hypot(p, e[i]);
                    e[i + 1] = s * r;
                    s = e[i] / r;
                    c = p / r;
                    p = c * d[i] - s * g;
                    d[i + 1] = h + s * (c * g + s * d[i]);
                    if VECTORS {
                        let (vi, vi1) = column_pair(v, n, i, i + 1);
                        for (a, b) in vi.iter_mut().zip(vi1.iter_mut()) {
                            let h = *b;
                            *b = s * *a + c * h;
                            *a = c * *a - s * h;
                        }
                    }
                }
                p = -s * s2 * c3 * el1 * e[l] / dl1;
                e[l] = s * p;
                d[l] = c * p;
                if !(e[l].abs() > eps * tst1) {
                    break;
                }
            }
        }
        d[l] += f;
        e[l] = 0.0;
    }
}

/// sqrt(x² + y²) by the plain formula, which vectorises and costs a fraction of `f64::hypot`,
/// except where the squares leave the range in which it is exact to rounding: an off-diagonal
/// many orders of magnitude below the diagonals beside it makes a QL shift p whose square
/// overflows, and QL then divided by ∞ (eigenvalues 0 and ∞, or NaN). Within the range the
/// result is the formula's, bit for bit, as before.
#[inline(always)]
fn hypot(x: f64, y: f64) -> f64 {
    let s = x * x + y * y;
    if (f64::MIN_POSITIVE / f64::EPSILON..f64::INFINITY).contains(&s) {
        s.sqrt()
    } else {
        x.hypot(y)
    }
}

/// Householder reduction of the symmetric n×n matrix in `v` (column-major, both triangles set)
/// to tridiagonal form, kept for [`tridiagonal_eigenvalues`], [`count_below`], [`bisect`] and
/// [`reduced_eigenvectors`]: on return `v` holds the reflectors, `h` their scales, `diag` and
/// `off` the tridiagonal (`off[i]` couples rows i − 1 and i; `off[0]` is 0).
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
pub fn reduce_tridiagonal(
    n: usize,
    v: &mut [f64],
    h: &mut [f64],
    diag: &mut [f64],
    off: &mut [f64],
) {
    assert!(v.len() == n * n && [h.len(), diag.len(), off.len()] == [n; 3]);
    if n == 0 {
        return;
    }
    reduce(n, v, h, off);
    off[0] = 0.0;
    for i in 0..n {
        diag[i] = v[i * n + i];
    }
}

/// All eigenvalues (unsorted) of the tridiagonal of [`reduce_tridiagonal`], by the same QL
/// iteration as [`symmetric_eigen`], so the same bits. `scratch`: n values.
pub fn tridiagonal_eigenvalues(diag: &[f64], off: &[f64], values: &mut [f64], scratch: &mut [f64]) {
    let n = diag.len();
    assert!([off.len(), values.len(), scratch.len()] == [n; 3]);
    if n == 0 {
        return;
    }
    values.copy_from_slice(diag);
    scratch.copy_from_slice(off);
    ql::<false>(n, &mut [], values, scratch);
}

/// The bounds of the Gershgorin discs of the tridiagonal, and the smallest pivot magnitude
/// allowed in its Sturm sequences (as LAPACK's dstebz).
pub fn gershgorin(diag: &[f64], off: &[f64]) -> (f64, f64, f64) {
    let n = diag.len();
    let (mut lo, mut hi, mut big) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
    for i in 0..n {
        let r = off[i].abs() + if i + 1 < n { off[i + 1].abs() } else { 0.0 };
        lo = lo.min(diag[i] - r);
        hi = hi.max(diag[i] + r);
        big = big.max(off[i] * off[i]);
    }
    (lo, hi, f64::MIN_POSITIVE * big.max(1.0))
}

/// How many eigenvalues of the tridiagonal (diag, off) lie below `x` (Sturm count: the number
/// of negative pivots of the LDLᵀ factorisation of T − x·I).
pub fn count_below(diag: &[f64], off: &[f64], x: f64, pivmin: f64) -> usize {
    let mut q = 1.0;
    let mut count = 0;
    for (d, e) in diag.iter().zip(off) {
        q = (d - x) - e * e / q;
        if q.abs() < pivmin {
            q = -pivmin;
        }
        count += usize::from(q < 0.0);
    }
    count
}

/// Lanes of [`bisect`]: Sturm sequences computed side by side, so that the divisions of
/// independent sequences overlap instead of waiting for each other.
pub const BISECT_LANES: usize = 8;

/// The eigenvalues of the tridiagonal (diag, off) of ascending index `index[l]` (0 = smallest),
/// by bisection from intervals [`lo[l]`, `hi[l]`] that must hold them (with no more than
/// `index[l]` eigenvalues below `lo[l]` and more than `index[l]` below `hi[l]`), to an
/// absolute width of 2ε·`scale`. Unused lanes may repeat a used one.
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
pub fn bisect(
    diag: &[f64],
    off: &[f64],
    pivmin: f64,
    scale: f64,
    index: [usize; BISECT_LANES],
    lo: &mut [f64; BISECT_LANES],
    hi: &mut [f64; BISECT_LANES],
) {
    let tol = 2.0 * f64::EPSILON * scale;
    let target = index.map(|k| k as f64);
    for _ in 0..200 {
        if (0..BISECT_LANES).all(|l| !(hi[l] - lo[l] > tol)) {
            break;
        }
        let mut x = [0.0; BISECT_LANES];
        for l in 0..BISECT_LANES {
            x[l] = 0.5 * (lo[l] + hi[l]);
        }
        let mut q = [1.0; BISECT_LANES];
        let mut count = [0.0; BISECT_LANES];
        for (d, e) in diag.iter().zip(off) {
            let e2 = e * e;
            for l in 0..BISECT_LANES {
                let t = (d - x[l]) - e2 / q[l];
                let t = if t.abs() < pivmin { -pivmin } else { t };
                q[l] = t;
                count[l] += if t < 0.0 { 1.0 } else { 0.0 };
            }
        }
        for l in 0..BISECT_LANES {
            if count[l] > target[l] {
                hi[l] = x[l];
            } else {
                lo[l] = x[l];
            }
        }
    }
}

/// Eigenvectors computed side by side by [`reduced_eigenvectors`]: the triangular solves of
/// inverse iteration are chains of dependent operations, and independent chains overlap.
pub const VECTOR_LANES: usize = 4;

/// The unit eigenvectors, into the columns of `z` (n × `mu.len()`, column-major), of the matrix
/// reduced by [`reduce_tridiagonal`] for its eigenvalues `mu` (at most [`VECTOR_LANES`]):
/// inverse iteration on the tridiagonal (LU with partial pivoting, fixed start vectors and a
/// fixed count of iterations, so the bits are reproducible). After every solve each vector is
/// orthogonalised against the unit vectors `previous` (tridiagonal coordinates, n each,
/// concatenated; they must be eigenvectors of the same matrix) and against the vectors of the
/// lanes before its own, so that eigenvalues that coincide get independent vectors; then all are
/// mapped back through the reflectors together. The vectors in tridiagonal coordinates are also
/// appended to `previous`. `work`: 6·[`VECTOR_LANES`]·n values.
#[multiversion::multiversion(targets("x86_64+avx2+fma", "x86_64+avx"))]
#[allow(clippy::too_many_arguments)]
pub fn reduced_eigenvectors(
    n: usize,
    v: &[f64],
    h: &[f64],
    diag: &[f64],
    off: &[f64],
    mu: &[f64],
    previous: &mut Vec<f64>,
    z: &mut [f64],
    work: &mut [f64],
) {
    const L: usize = VECTOR_LANES;
    let count = mu.len();
    assert!(v.len() == n * n && count <= L && z.len() == n * count && work.len() == 6 * L * n);
    assert!(previous.len().is_multiple_of(n.max(1)));
    if n == 0 || count == 0 {
        return;
    }
    // Lane-interleaved: entry i of lane l at i·L + l, so that a step of the solves advances every
    // lane with one vector operation. Unused lanes repeat the last shift; their results are
    // dropped, and no used lane is orthogonalised against them.
    let shift: [f64; L] = std::array::from_fn(|l| mu[l.min(count - 1)]);
    let (inv, rest) = work.split_at_mut(L * n);
    let (du, rest) = rest.split_at_mut(L * n);
    let (dl, rest) = rest.split_at_mut(L * n);
    let (du2, rest) = rest.split_at_mut(L * n);
    let (swapped, y) = rest.split_at_mut(L * n);
    let mut norm: f64 = 0.0;
    for i in 0..n {
        let sub = if i + 1 < n { off[i + 1] } else { 0.0 };
        norm = norm.max(diag[i].abs() + off[i].abs() + sub.abs());
        for l in 0..L {
            inv[i * L + l] = diag[i] - shift[l];
            du[i * L + l] = sub;
            dl[i * L + l] = sub;
            du2[i * L + l] = 0.0;
        }
    }
    // LU of T − μI with row interchanges (LAPACK dgttrf's scheme), written with selects instead
    // of branches: the lanes pivot differently, and a branch per lane would mispredict.
    for i in 0..n - 1 {
        let (cur, next) = (i * L, (i + 1) * L);
        for l in 0..L {
            let (a, b, c, d) = (inv[cur + l], dl[cur + l], du[cur + l], inv[next + l]);
            let sw = a.abs() < b.abs();
            let (num, den) = if sw { (a, b) } else { (b, a) };
            // den = 0 only without interchange, when the column below is 0 too: nothing to do.
            let f = if den != 0.0 { num / den } else { 0.0 };
            inv[cur + l] = if sw { b } else { a };
            dl[cur + l] = f;
            du[cur + l] = if sw { d } else { c };
            inv[next + l] = if sw { c - f * d } else { d - f * c };
            swapped[cur + l] = if sw { 1.0 } else { 0.0 };
            if i + 2 < n {
                let e = du[next + l];
                du2[cur + l] = if sw { e } else { 0.0 };
                du[next + l] = if sw { e * -f } else { e };
            }
        }
    }
    // A pivot that vanishes (μ is an eigenvalue to working precision) becomes the size of the
    // rounding in μ: the solve then grows the wanted eigenvector by ~1/ε. The pivots are kept
    // as reciprocals: the solves multiply, which keeps divisions out of their dependency chains.
    let tiny = (f64::EPSILON * norm).max(f64::MIN_POSITIVE);
    for p in inv.iter_mut() {
        if p.abs() < tiny {
            *p = if *p < 0.0 { -tiny } else { tiny };
        }
        *p = 1.0 / *p;
    }
    // Fixed start vectors with entries of mixed sizes and signs (no eigenvector of a symmetric
    // tridiagonal is orthogonal to one except by accident; the orthogonalisation handles repeats).
    for l in 0..L {
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15 ^ ((previous.len() + l * n) as u64);
        for i in 0..n {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            y[i * L + l] = ((state >> 11) as f64) / ((1u64 << 53) as f64) - 0.5;
        }
    }
    for _ in 0..3 {
        for i in 0..n - 1 {
            let (cur, next) = (i * L, (i + 1) * L);
            for l in 0..L {
                let (a, b) = (y[cur + l], y[next + l]);
                let (p, q) = if swapped[cur + l] != 0.0 {
                    (b, a)
                } else {
                    (a, b)
                };
                y[cur + l] = p;
                y[next + l] = q - dl[cur + l] * p;
            }
        }
        let last = (n - 1) * L;
        for l in 0..L {
            y[last + l] *= inv[last + l];
        }
        if n > 1 {
            let at = (n - 2) * L;
            for l in 0..L {
                y[at + l] = (y[at + l] - du[at + l] * y[at + L + l]) * inv[at + l];
            }
        }
        for i in (0..n.saturating_sub(2)).rev() {
            let at = i * L;
            for l in 0..L {
                y[at + l] =
                    (y[at + l] - du[at + l] * y[at + L + l] - du2[at + l] * y[at + 2 * L + l])
                        * inv[at + l];
            }
        }
        normalise_lanes(y, [true; L]);
        for q in previous.chunks_exact(n) {
            let c = lane_dot(q, y);
            for (row, qi) in y.chunks_exact_mut(L).zip(q) {
                for l in 0..L {
                    row[l] -= c[l] * qi;
                }
            }
        }
        for l in 0..L {
            for m in 0..l {
                let mut acc = [0.0; 4];
                for rows in y.chunks(4 * L) {
                    for (a, row) in acc.iter_mut().zip(rows.chunks_exact(L)) {
                        *a += row[m] * row[l];
                    }
                }
                let c = (acc[0] + acc[1]) + (acc[2] + acc[3]);
                for row in y.chunks_exact_mut(L) {
                    row[l] -= c * row[m];
                }
            }
            normalise_lanes(y, std::array::from_fn(|m| m == l));
        }
    }
    for l in 0..count {
        previous.extend(y.chunks_exact(L).map(|row| row[l]));
    }
    // Z = Q·Y with Q = P_{n−1}⋯P_1 (the reduction applied P_{n−1} first), every lane at once.
    for s in 1..n {
        if h[s] != 0.0 {
            let u = &v[s * n..s * n + s];
            let mut g = lane_dot(u, &y[..s * L]);
            for gl in g.iter_mut() {
                *gl /= h[s];
            }
            for (row, uk) in y[..s * L].chunks_exact_mut(L).zip(u) {
                for l in 0..L {
                    row[l] -= g[l] * uk;
                }
            }
        }
    }
    for (l, col) in z.chunks_exact_mut(n).enumerate() {
        for (zi, row) in col.iter_mut().zip(y.chunks_exact(L)) {
            *zi = row[l];
        }
    }
}

/// Σ_i q_i·y_{i,l} for every lane l of the lane-interleaved `y` (rows of [`VECTOR_LANES`]),
/// with two accumulators per lane so that the sums pipeline.
#[inline(always)]
fn lane_dot(q: &[f64], y: &[f64]) -> [f64; VECTOR_LANES] {
    const L: usize = VECTOR_LANES;
    let (mut a, mut b) = ([0.0; L], [0.0; L]);
    let pairs = q.len() / 2;
    for k in 0..pairs {
        let (r0, r1) = (
            &y[2 * k * L..(2 * k + 1) * L],
            &y[(2 * k + 1) * L..(2 * k + 2) * L],
        );
        for l in 0..L {
            a[l] += q[2 * k] * r0[l];
            b[l] += q[2 * k + 1] * r1[l];
        }
    }
    if q.len() % 2 == 1 {
        let k = q.len() - 1;
        for l in 0..L {
            a[l] += q[k] * y[k * L + l];
        }
    }
    std::array::from_fn(|l| a[l] + b[l])
}

/// Scales the lanes `which` of the lane-interleaved `y` to unit length (a zero lane becomes the
/// first unit vector), all lanes' sums side by side.
#[inline(always)]
fn normalise_lanes(y: &mut [f64], which: [bool; VECTOR_LANES]) {
    const L: usize = VECTOR_LANES;
    let mut big = [0.0f64; L];
    for row in y.chunks_exact(L) {
        for l in 0..L {
            big[l] = big[l].max(row[l].abs());
        }
    }
    // Dividing by the largest entry first keeps the sum of squares from overflowing after a
    // solve that grew the vector by ~1/ε.
    let usable: [bool; L] = std::array::from_fn(|l| which[l] && big[l] > 0.0 && big[l].is_finite());
    let inv: [f64; L] = std::array::from_fn(|l| if usable[l] { 1.0 / big[l] } else { 0.0 });
    let mut sums = [[0.0; L]; 4];
    for rows in y.chunks(4 * L) {
        for (acc, row) in sums.iter_mut().zip(rows.chunks_exact(L)) {
            for l in 0..L {
                let x = row[l] * inv[l];
                acc[l] += x * x;
            }
        }
    }
    let scale: [f64; L] = std::array::from_fn(|l| {
        if usable[l] {
            inv[l] / ((sums[0][l] + sums[1][l]) + (sums[2][l] + sums[3][l])).sqrt()
        } else {
            1.0
        }
    });
    for row in y.chunks_exact_mut(L) {
        for l in 0..L {
            row[l] *= scale[l];
        }
    }
    for l in 0..L {
        if which[l] && big[l] == 0.0 {
            y[l] = 1.0;
        }
    }
}

/// Σ a_k·b_k with four independent accumulators (a single chain is latency-bound).
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            acc[l] += x[l] * y[l];
        }
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// Mutable columns `a` and `b` (a ≠ b) of a column-major n×n matrix.
#[inline(always)]
fn column_pair(v: &mut [f64], n: usize, a: usize, b: usize) -> (&mut [f64], &mut [f64]) {
    debug_assert_ne!(a, b);
    if a < b {
        let (lo, hi) = v.split_at_mut(b * n);
        (&mut lo[a * n..a * n + n], &mut hi[..n])
    } else {
        let (lo, hi) = v.split_at_mut(a * n);
        (&mut hi[..n], &mut lo[b * n..b * n + n])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use rand::{Rng, SeedableRng};

    #[test]
    fn decomposes_random_symmetric_matrices() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        for trial in 0..200 {
            let n = 1 + trial % 40;
            let b = DMatrix::from_fn(n, n, |_, _| rng.random_range(-3.0..3.0));
            // PSD with a wide spread of eigenvalues, as the per-step matrices have.
            let scale = DMatrix::from_fn(n, n, |i, j| {
                if i == j {
                    10f64.powf(rng.random_range(-6.0..2.0))
                } else {
                    0.0
                }
            });
            let a = if trial % 2 == 0 {
                &b * &scale * b.transpose()
            } else {
                (&b + b.transpose()) * 0.5
            };
            let mut v = a.as_slice().to_vec();
            let (mut d, mut e) = (vec![0.0; n], vec![0.0; n]);
            symmetric_eigen(n, &mut v, &mut d, &mut e);
            let vm = DMatrix::from_column_slice(n, n, &v);
            let rebuilt = &vm
                * DMatrix::from_diagonal(&nalgebra::DVector::from_vec(d.clone()))
                * vm.transpose();
            let tol = 1e-12 * (1.0 + a.amax()) * n as f64;
            assert!(
                (&rebuilt - &a).amax() < tol,
                "n = {n}: reconstruction off by {}",
                (&rebuilt - &a).amax()
            );
            assert!((vm.transpose() * &vm - DMatrix::identity(n, n)).amax() < 1e-12 * n as f64);
            let mut ours = d.clone();
            let mut theirs: Vec<f64> = a.clone().symmetric_eigenvalues().iter().cloned().collect();
            ours.sort_by(f64::total_cmp);
            theirs.sort_by(f64::total_cmp);
            for (x, y) in ours.iter().zip(&theirs) {
                assert!((x - y).abs() < tol, "{x} vs {y}");
            }
        }
    }

    /// λ (the largest eigenvalue alone) is the largest of the full decomposition's, bit for
    /// bit, at every scale (scaled matrices go through the same power-of-2 path).
    #[test]
    fn largest_eigenvalue_is_the_full_decompositions() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for trial in 0..60 {
            let n = 1 + trial % 30;
            let b = DMatrix::from_fn(n, n, |_, _| rng.random_range(-2.0..2.0));
            let a = &b * b.transpose();
            let a = (&a + a.transpose()) * 0.5;
            for scale in [1.0, 1e-300, 1e300] {
                let a = &a * scale;
                let mut full = a.as_slice().to_vec();
                let (mut d, mut e) = (vec![0.0; n], vec![0.0; n]);
                symmetric_eigen(n, &mut full, &mut d, &mut e);
                let expected = d.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                let mut v = a.as_slice().to_vec();
                let mut scratch = vec![0.0; 3 * n];
                let got = largest_eigenvalue(n, &mut v, &mut scratch);
                assert_eq!(
                    got.to_bits(),
                    expected.to_bits(),
                    "n = {n}, scale {scale:e}"
                );
                assert!(
                    got.is_finite() && got > 0.0,
                    "n = {n}, scale {scale:e}: {got}"
                );
            }
        }
        assert_eq!(largest_eigenvalue(0, &mut [], &mut []), 0.0);
    }

    /// The pieces of the partial path: Sturm counts and bisection agree with the eigenvalues of
    /// the full decomposition, and inverse iteration gives orthonormal eigenvectors with small
    /// residuals, also for an eigenvalue of multiplicity 3 (a matrix of rank n − 3).
    #[test]
    fn partial_decomposition_matches_the_full_one() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for trial in 0..60 {
            let n = 3 + trial % 37;
            let r = if trial % 3 == 0 { n - 3 } else { n };
            let b = DMatrix::from_fn(n, r.max(1), |_, _| rng.random_range(-2.0..2.0));
            let a = &b * b.transpose();
            let a = (&a + a.transpose()) * 0.5;
            let mut full = a.as_slice().to_vec();
            let (mut d, mut e) = (vec![0.0; n], vec![0.0; n]);
            symmetric_eigen(n, &mut full, &mut d, &mut e);
            let mut sorted = d.clone();
            sorted.sort_by(f64::total_cmp);

            let mut v = a.as_slice().to_vec();
            let (mut h, mut diag, mut off) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
            reduce_tridiagonal(n, &mut v, &mut h, &mut diag, &mut off);
            let (mut values, mut scratch) = (vec![0.0; n], vec![0.0; n]);
            tridiagonal_eigenvalues(&diag, &off, &mut values, &mut scratch);
            assert_eq!(values, d, "the same QL on the same tridiagonal");
            let (gl, gu, pivmin) = gershgorin(&diag, &off);
            let scale = gl.abs().max(gu.abs());
            let tol = 1e-13 * scale * n as f64;
            let x = 0.5 * (sorted[n / 2] + sorted[n / 2 - 1]);
            if sorted[n / 2] - sorted[n / 2 - 1] > 2.0 * tol {
                assert_eq!(count_below(&diag, &off, x, pivmin), n / 2);
            }
            let mut previous = Vec::new();
            let mut work = vec![0.0; 6 * VECTOR_LANES * n];
            let mut vectors = Vec::new();
            for start in (0..n).step_by(BISECT_LANES) {
                let lanes = BISECT_LANES.min(n - start);
                let index: [usize; BISECT_LANES] =
                    std::array::from_fn(|l| start + l.min(lanes - 1));
                let (mut lo, mut hi) = ([gl - tol; BISECT_LANES], [gu + tol; BISECT_LANES]);
                bisect(&diag, &off, pivmin, scale, index, &mut lo, &mut hi);
                let mu: Vec<f64> = (0..lanes).map(|l| 0.5 * (lo[l] + hi[l])).collect();
                for (l, m) in mu.iter().enumerate() {
                    assert!(
                        (m - sorted[start + l]).abs() < tol,
                        "{m} vs {}",
                        sorted[start + l]
                    );
                }
                // Groups of every size up to the lanes, so that partly used groups are covered.
                let mut at = 0;
                let mut size = 1 + trial % VECTOR_LANES;
                while at < lanes {
                    let take = size.min(lanes - at);
                    let mut z = vec![0.0; n * take];
                    reduced_eigenvectors(
                        n,
                        &v,
                        &h,
                        &diag,
                        &off,
                        &mu[at..at + take],
                        &mut previous,
                        &mut z,
                        &mut work,
                    );
                    for (zl, m) in z.chunks_exact(n).zip(&mu[at..at + take]) {
                        let zv = nalgebra::DVector::from_column_slice(zl);
                        let residual = (&a * &zv - &zv * *m).amax();
                        assert!(residual < tol, "n = {n}, rank {r}: residual {residual:e}");
                        vectors.push(zv);
                    }
                    at += take;
                    size = size % VECTOR_LANES + 1;
                }
            }
            let zm = DMatrix::from_columns(&vectors);
            assert!((zm.transpose() * &zm - DMatrix::identity(n, n)).amax() < 1e-12 * n as f64);
        }
    }

    /// A covariance driven towards 0 (CEM, or λ_min = 0, over many updates) or made huge has
    /// entries far from 1: the QL rotations' sqrt(p² + e²) underflowed to 0 (entries near
    /// 1e-300) or overflowed (a p of 1e160 from tiny off-diagonals), and the eigenvalues came out
    /// ±inf or NaN, which the sampler turned into NaN parameters. Scaled matrices must decompose
    /// as well as unscaled ones, relative to their size.
    #[test]
    fn decomposes_matrices_of_any_scale() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
        for scale in [
            1e-305, 1e-300, 1e-250, 1e-200, 1e-160, 1e-32, 1e150, 1e200, 1e300,
        ] {
            for trial in 0..40 {
                let n = 3 + trial % 30;
                // Rank n/3: most eigenvalues are 0 to rounding, as in a low-rank covariance.
                let b = DMatrix::from_fn(n, (n / 3).max(1), |_, _| rng.random_range(-1.0..1.0));
                let a = &b * b.transpose() * (scale / n as f64);
                let a = (&a + a.transpose()) * 0.5;
                let mut v = a.as_slice().to_vec();
                let (mut d, mut e) = (vec![0.0; n], vec![0.0; n]);
                symmetric_eigen(n, &mut v, &mut d, &mut e);
                assert!(
                    d.iter().chain(&v).all(|x| x.is_finite()),
                    "scale {scale:e}, n = {n}: eigenvalues {d:?}"
                );
                let vm = DMatrix::from_column_slice(n, n, &v);
                let rebuilt = &vm
                    * DMatrix::from_diagonal(&nalgebra::DVector::from_vec(d.clone()))
                    * vm.transpose();
                let off = (&rebuilt - &a).amax() / a.amax();
                assert!(
                    off < 1e-12 * n as f64,
                    "scale {scale:e}, n = {n}: off by {off:e}"
                );
            }
        }
        // Within the range, an off-diagonal 1e-190 beside diagonals 1e-200 and 1 made QL's first
        // shift p = (1 − 1e-200)/(2·1e-190) ≈ 5e189, whose square overflowed: eigenvalues 0 and
        // ∞ instead of 1e-200 and 1 (the CEM run of P = 200 that drew NaN parameters).
        #[rustfmt::skip]
        let a = DMatrix::from_row_slice(3, 3, &[
            1e-200, 1e-190, 0.0,
            1e-190, 1.0, 0.0,
            0.0, 0.0, 2.0,
        ]);
        let mut v = a.as_slice().to_vec();
        let (mut d, mut e) = (vec![0.0; 3], vec![0.0; 3]);
        symmetric_eigen(3, &mut v, &mut d, &mut e);
        d.sort_by(f64::total_cmp);
        assert!(
            (d[0] / 1e-200 - 1.0).abs() < 1e-12 && d[1] == 1.0 && d[2] == 2.0,
            "{d:?}"
        );
    }

    /// A NaN entry must neither hang the QL iteration nor come out as finite eigenvalues that
    /// look valid. Run on a thread with a generous bound, so that a hang fails the test instead
    /// of stalling the suite (this bounds a hang; it does not time the decomposition).
    #[test]
    fn nan_input_terminates() {
        let (done, finished) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut v = vec![f64::NAN, 1.0, 1.0, 2.0];
            let (mut d, mut e) = (vec![0.0; 2], vec![0.0; 2]);
            symmetric_eigen(2, &mut v, &mut d, &mut e);
            // λ alone (the QL without eigenvectors) must end too.
            let mut v = vec![1.0, 0.5, 0.0, 0.5, f64::NAN, 0.5, 0.0, 0.5, 1.0];
            let _ = largest_eigenvalue(3, &mut v, &mut [0.0; 9]);
            let _ = done.send(d);
        });
        let d = finished
            .recv_timeout(std::time::Duration::from_secs(30))
            .expect("the decomposition of a NaN matrix did not return");
        assert!(d.iter().any(|x| x.is_nan()), "NaN in, finite out: {d:?}");
    }
}
