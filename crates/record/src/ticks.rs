//! Axis ticks for every figure the project draws (`analyze`, `pi2cma run`/`experiment`'s fig2,
//! the T-ball example): where the ticks go and how they are labelled.
//!
//! Plotters' own labels were `0.0, 5.0, 10.0` on an update axis, `10000.0` on a λ axis, `-0.0`
//! at zero, and ran together on a narrow axis (`-1.0-0.8-0.6`). Here a label has the fewest
//! decimals that tell the ticks apart, never `-0`, and the ticks are spread so that no two
//! labels overlap, with a label's width estimated from its characters and the font size.
//!
//! Use with plotters: build the chart on `ticks.on(lo, hi)` (or `ticks.on_log(lo, hi)`), an
//! [`Axis`] that puts plotters' ticks and labels where these are. (Plotters' own
//! `with_key_points` loses the formatting of an f64 axis: no mesh can be drawn on it.)

use std::ops::Range;

use plotters::coord::ranged1d::{KeyPointHint, NoDefaultFormatting, Ranged, ValueFormatter};

/// The tick labels' font size in pixels as plotters sizes its default label font (12; the SVG
/// backend draws it smaller, so the estimate errs on the wide side).
pub(crate) const FONT_PX: f64 = 12.0;

/// Width of a character of a tick label as a fraction of the font size (digits, '.', '-' in a
/// sans-serif font are narrower).
const CHAR_EM: f64 = 0.6;

/// Free space between two neighbouring labels along a horizontal axis, in pixels.
const GAP_PX: f64 = 8.0;

/// The least distance between two ticks, in pixels, along a horizontal and a vertical axis:
/// short labels packed as closely as they fit crowd the axis.
const MIN_SPACING_PX: [f64; 2] = [50.0, 30.0];

/// The estimated width in pixels of a label `text` at the figures' font size.
pub fn label_width(text: &str) -> f64 {
    text.chars().count() as f64 * CHAR_EM * FONT_PX
}

/// Which way an axis runs: along a horizontal axis labels sit side by side (their widths
/// count), along a vertical one they are stacked (their height counts).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Along {
    /// An x axis.
    Horizontal,
    /// A y axis.
    Vertical,
}

/// The ticks of one axis: their values, ascending, and their labels.
#[derive(Clone, Debug, PartialEq)]
pub struct Ticks {
    /// Where the ticks are, in data units.
    pub values: Vec<f64>,
    /// What each tick is labelled (one per value).
    pub labels: Vec<String>,
}

impl Ticks {
    /// Ticks of a linear axis from `lo` to `hi` drawn `pixels` long: at multiples of 1, 2 or 5
    /// × 10^k, as close together as the labels allow.
    pub fn linear(lo: f64, hi: f64, pixels: f64, along: Along) -> Self {
        let (lo, hi) = ordered(lo, hi);
        let at = |v: f64| (v - lo) / (hi - lo) * pixels;
        let span = hi - lo;
        if !(span > 0.0 && span.is_finite()) {
            return Self::from_values(vec![lo], 0);
        }
        let exp = (span / 100.0).log10().floor();
        // A span of subnormals: no step of 1, 2, 5 × 10^k below it is representable.
        if !exp.is_finite() || exp < f64::from(f64::MIN_10_EXP) {
            return Self::from_values(vec![lo], 0);
        }
        let mut exp = exp as i32;
        loop {
            for m in [1.0, 2.0, 5.0] {
                let step = m * 10f64.powi(exp);
                let decimals = (-exp).max(0) as usize;
                let first = (lo / step - 1e-9).ceil() as i64;
                let last = (hi / step + 1e-9).floor() as i64;
                // Far more ticks than any axis can label: a wider step.
                if last.saturating_sub(first) > 10_000 {
                    continue;
                }
                let values: Vec<f64> = (first..=last).map(|i| i as f64 * step).collect();
                let t = Self::from_values(values, decimals);
                if t.values.len() <= 1 || t.fits(at, along) {
                    return t;
                }
            }
            exp += 1;
        }
    }

    /// Ticks of a log axis from `lo` to `hi` (both > 0) drawn `pixels` long: at 1, 2, 5 × 10^k
    /// where there is room, else at every, every second, … power of ten; over less than a
    /// decade, where no two powers of ten fit, the linear ticks.
    pub fn log(lo: f64, hi: f64, pixels: f64, along: Along) -> Self {
        let (lo, hi) = ordered(lo, hi);
        if !(lo > 0.0 && hi > lo && hi.is_finite()) {
            return Self::linear(lo, hi, pixels, along);
        }
        let (llo, lhi) = (lo.log10(), hi.log10());
        let at = |v: f64| (v.log10() - llo) / (lhi - llo) * pixels;
        let (k0, k1) = (llo.floor() as i32, lhi.ceil() as i32);
        let within = |v: f64| v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9);
        let powers = |every: i32, mantissas: &[f64]| -> Self {
            let mut values = Vec::new();
            let mut labels = Vec::new();
            for k in k0..=k1 {
                if k.rem_euclid(every) != 0 {
                    continue;
                }
                for &m in mantissas {
                    let v = m * 10f64.powi(k);
                    if within(v) {
                        values.push(v);
                        labels.push(power_label(m, k));
                    }
                }
            }
            Self { values, labels }
        };
        let mut candidates = vec![powers(1, &[1.0, 2.0, 5.0])];
        candidates.extend((1..=(k1 - k0).max(1)).map(|every| powers(every, &[1.0])));
        for t in candidates {
            if t.values.len() >= 2 && t.fits(at, along) {
                return t;
            }
        }
        // Less than a decade: linear ticks, spaced as they fall on the log axis.
        let lin = Self::linear(lo, hi, pixels, along);
        if lin.values.len() >= 2 && lin.fits(at, along) {
            return lin;
        }
        // Too short for two labels: the ends' power of ten alone.
        powers(1, &[1.0])
    }

    /// The ticks at `values` labelled with `decimals` decimals (zero as `0`, never `-0`).
    fn from_values(values: Vec<f64>, decimals: usize) -> Self {
        let values: Vec<f64> = values
            .into_iter()
            // -0.0 (an axis ending at it) is 0; a tiny value is a tick of a tiny axis.
            .map(|v| if v == 0.0 { 0.0 } else { v })
            .collect();
        let labels = values.iter().map(|v| fixed(*v, decimals)).collect();
        Self { values, labels }
    }

    /// Whether no two neighbouring labels overlap, `at` giving a value's pixel on the axis.
    fn fits(&self, at: impl Fn(f64) -> f64, along: Along) -> bool {
        self.values
            .windows(2)
            .zip(self.labels.windows(2))
            .all(|(v, l)| {
                let gap = (at(v[1]) - at(v[0])).abs();
                match along {
                    Along::Horizontal => {
                        gap >= MIN_SPACING_PX[0]
                            && gap >= 0.5 * (label_width(&l[0]) + label_width(&l[1])) + GAP_PX
                    }
                    Along::Vertical => gap >= MIN_SPACING_PX[1].max(1.6 * FONT_PX),
                }
            })
    }

    /// The label of the tick nearest `v` (plotters asks for the labels of the values it was
    /// given, as floats).
    pub fn label(&self, v: f64) -> String {
        self.values
            .iter()
            .zip(&self.labels)
            .min_by(|a, b| (a.0 - v).abs().total_cmp(&(b.0 - v).abs()))
            .map(|(_, l)| l.clone())
            .unwrap_or_default()
    }
}

impl Ticks {
    /// A linear plotters axis from `lo` to `hi` with these ticks.
    pub fn on(&self, lo: f64, hi: f64) -> Axis {
        Axis {
            range: lo..hi,
            log: false,
            ticks: self.clone(),
        }
    }

    /// A log plotters axis from `lo` to `hi` (> 0) with these ticks; a value at or below zero
    /// is drawn at `lo`.
    pub fn on_log(&self, lo: f64, hi: f64) -> Axis {
        Axis {
            range: lo..hi,
            log: true,
            ticks: self.clone(),
        }
    }
}

/// A plotters axis whose ticks and labels are a [`Ticks`]'.
pub struct Axis {
    range: Range<f64>,
    log: bool,
    ticks: Ticks,
}

impl Ranged for Axis {
    type FormatOption = NoDefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let (lo, hi) = (self.range.start, self.range.end);
        let f = if self.log {
            (value.max(lo).ln() - lo.ln()) / (hi.ln() - lo.ln())
        } else {
            (value - lo) / (hi - lo)
        };
        let f = if f.is_finite() { f } else { 0.0 };
        limit.0 + (f * f64::from(limit.1 - limit.0)).round() as i32
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        // No light mesh lines: the grid is the ticks'.
        if hint.weight().allow_light_points() {
            Vec::new()
        } else {
            self.ticks.values.clone()
        }
    }

    fn range(&self) -> Range<f64> {
        self.range.clone()
    }
}

impl ValueFormatter<f64> for Axis {
    fn format_ext(&self, value: &f64) -> String {
        self.ticks.label(*value)
    }
}

fn ordered(a: f64, b: f64) -> (f64, f64) {
    if a <= b {
        (a, b)
    } else {
        (b, a)
    }
}

/// `v` with `decimals` decimals, `0` rather than `-0`.
fn fixed(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// `m` × 10^`k` as plain digits where they are short (10^-4 to 10^5), else as `me k`.
fn power_label(m: f64, k: i32) -> String {
    if (-4..=5).contains(&k) {
        fixed(m * 10f64.powi(k), (-k).max(0) as usize)
    } else {
        format!("{m}e{k}")
    }
}

/// The plotting area's size in pixels of a chart drawn on an area `area` (width, height) with
/// `margin` on every side, label areas `left`, `right` and `bottom` wide, and a caption in a
/// `caption` px font (0: none): what [`Ticks`] needs before plotters lays the chart out.
pub fn plot_size(
    area: (u32, u32),
    margin: u32,
    left: u32,
    right: u32,
    bottom: u32,
    caption: u32,
) -> (f64, f64) {
    let caption = if caption > 0 {
        f64::from(caption) + f64::from(margin)
    } else {
        0.0
    };
    (
        (f64::from(area.0) - f64::from(2 * margin + left + right)).max(1.0),
        (f64::from(area.1) - f64::from(2 * margin + bottom) - caption).max(1.0),
    )
}

/// The x and y ranges that show `x` and `y` on a `w` × `h` pixel plot at one scale (a metre,
/// or a unit of θ, as long across as up): the tighter one widened about its middle.
pub fn equal_scale(x: (f64, f64), y: (f64, f64), w: f64, h: f64) -> ((f64, f64), (f64, f64)) {
    let per_pixel = ((x.1 - x.0) / w).max((y.1 - y.0) / h);
    let widen = |(a, b): (f64, f64), pixels: f64| {
        let mid = 0.5 * (a + b);
        (
            mid - 0.5 * per_pixel * pixels,
            mid + 0.5 * per_pixel * pixels,
        )
    };
    (widen(x, w), widen(y, h))
}

/// Whether a cost axis should be logarithmic: every value plotted is positive and they span
/// more than two decades (a run whose cost falls from 80 to 0.05 is a flat line after its
/// second update on a linear axis).
pub(crate) fn wants_log(values: impl IntoIterator<Item = f64>) -> bool {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.into_iter().filter(|v| v.is_finite()) {
        if v <= 0.0 {
            return false;
        }
        lo = lo.min(v);
        hi = hi.max(v);
    }
    lo.is_finite() && hi / lo > 100.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Ranges no figure of a real run has, found by a review: a span of subnormals panicked
    /// ("capacity overflow" collecting ~2^64 ticks); a range of 1e-13 got one tick, 0, outside
    /// it.
    #[test]
    fn odd_ranges_give_ticks_within_them_and_never_panic() {
        let t = Ticks::linear(-5e-324, 5e-324, 400.0, Along::Horizontal);
        assert_eq!(t.values.len(), 1, "{t:?}");
        let t = Ticks::linear(1e-13, 5e-13, 400.0, Along::Horizontal);
        assert!(t.values.len() >= 2, "{t:?}");
        assert!(
            t.values
                .iter()
                .all(|v| (1e-13 * (1.0 - 1e-9)..=5e-13 * (1.0 + 1e-9)).contains(v)),
            "{t:?}"
        );
        for (lo, hi) in [
            (f64::NAN, 1.0),
            (0.0, f64::INFINITY),
            (3.0, 3.0),
            (-1e300, 1e300),
        ] {
            let t = Ticks::linear(lo, hi, 400.0, Along::Vertical);
            assert!(!t.values.is_empty(), "{lo} {hi}: {t:?}");
        }
    }

    fn check(t: &Ticks, lo: f64, hi: f64, pixels: f64, log: bool) {
        assert!(t.values.len() >= 2, "{t:?}");
        let mut distinct = t.labels.clone();
        distinct.dedup();
        assert_eq!(distinct.len(), t.labels.len(), "labels repeat: {t:?}");
        for l in &t.labels {
            let minus_zero = l.starts_with('-') && l[1..].chars().all(|c| c == '0' || c == '.');
            assert!(!minus_zero, "{l} in {t:?}");
        }
        // Where every tick is an integer, no label has decimals (a step of 0.5 labels `1.0`
        // like `1.5`, as it should).
        if t.values.iter().all(|v| v.fract() == 0.0) {
            assert!(t.labels.iter().all(|l| !l.contains('.')), "{t:?}");
        }
        // Labels centred on their ticks do not overlap along a horizontal axis.
        let at = |v: f64| {
            if log {
                (v.ln() - lo.ln()) / (hi.ln() - lo.ln()) * pixels
            } else {
                (v - lo) / (hi - lo) * pixels
            }
        };
        for (v, l) in t.values.windows(2).zip(t.labels.windows(2)) {
            let room = at(v[1]) - at(v[0]);
            let need = 0.5 * (label_width(&l[0]) + label_width(&l[1]));
            assert!(room > need, "{l:?} overlap: {room} px for {need} px: {t:?}");
        }
    }

    /// Found by a user test of the README: `0.0, 5.0` on update axes, `10000.0` on λ axes,
    /// `-0.0`, and labels running together on a narrow axis (`-1.0-0.8-0.6-0.4-0.2-0.0`).
    #[test]
    fn labels_are_distinct_short_without_minus_zero_and_do_not_overlap() {
        for (lo, hi, px) in [
            (0.0, 40.0, 450.0),
            (0.0, 40.0, 120.0),
            (-1.2, 0.6, 180.0),
            (-2.5, 0.5, 180.0),
            (-0.3, 0.3, 900.0),
            (0.0, 12345.0, 300.0),
            (-750.0, -250.0, 330.0),
            (0.001, 0.0013, 500.0),
            (99990.0, 100010.0, 400.0),
        ] {
            let t = Ticks::linear(lo, hi, px, Along::Horizontal);
            check(&t, lo, hi, px, false);
            if lo < 0.0 && hi > 0.0 {
                assert!(t.values.contains(&0.0), "{t:?}");
            }
        }
        assert_eq!(
            Ticks::linear(0.0, 40.0, 450.0, Along::Horizontal).labels,
            ["0", "5", "10", "15", "20", "25", "30", "35", "40"]
        );
        for (lo, hi, px) in [
            (5.0, 20000.0, 150.0),
            (1e-7, 1e3, 200.0),
            (0.05, 80.0, 400.0),
            (3.0, 7.0, 300.0),
        ] {
            let t = Ticks::log(lo, hi, px, Along::Horizontal);
            check(&t, lo, hi, px, true);
        }
        let t = Ticks::log(5.0, 20000.0, 400.0, Along::Vertical);
        assert!(t.labels.contains(&"10000".to_string()), "{t:?}");
        // Stacked labels keep 30 px apart.
        let t = Ticks::linear(-750.0, -250.0, 100.0, Along::Vertical);
        assert!(
            t.values.len() >= 2 && t.values.len() <= 100 / 30 + 1,
            "{t:?}"
        );
    }

    #[test]
    fn a_cost_axis_is_logarithmic_over_more_than_two_decades_of_positive_costs() {
        assert!(wants_log([80.0, 3.0, 0.05]));
        assert!(!wants_log([80.0, 3.0, 1.0]));
        assert!(!wants_log([80.0, 0.0, 0.05]));
        assert!(!wants_log([]));
    }
}
