//! SVG plots of estimates against the truth: what a person looks at first.

use std::fmt::Write as _;
use vlsync_common::{nanos_to_secs, Estimate, EstimatorState, Nanos};

const W: f64 = 1000.0;
const H: f64 = 420.0;
const L: f64 = 70.0;
const R: f64 = 20.0;
const T: f64 = 40.0;
const B: f64 = 50.0;
/// Largest |offset| plotted, ms (1e12 s); beyond it, and NaN/inf, values are left out.
const MAX_PLOT_MS: f64 = 1e15;
/// Most grid lines per axis (the tick step gives about 8).
const MAX_TICKS: u32 = 100;

fn color(s: EstimatorState) -> &'static str {
    match s {
        EstimatorState::Tracking => "#1a7f37",
        EstimatorState::Holding => "#bf8700",
        EstimatorState::Acquiring => "#8c959f",
        EstimatorState::Lost => "#cf222e",
    }
}

/// A nice tick step for a range.
fn tick_step(range: f64) -> f64 {
    let raw = range / 8.0;
    let mag = 10f64.powf(raw.abs().max(1e-12).log10().floor());
    let n = raw / mag;
    mag * if n < 1.5 {
        1.0
    } else if n < 3.5 {
        2.0
    } else if n < 7.5 {
        5.0
    } else {
        10.0
    }
}

/// Offset (ms) against LiDAR time (s): the estimate with its ±2σ band, the raw
/// correlation measurements, the truth when known, states as coloured marks, and
/// optional shaded intervals (e.g. load phases) with labels.
pub fn offset_svg(
    title: &str,
    ests: &[Estimate],
    truth: Option<&[(Nanos, f64)]>,
    shaded: &[(Nanos, Nanos, String)],
) -> String {
    offset_svg_compared(title, ests, truth, shaded, &[])
}

/// [`offset_svg`] with another run's locked estimates drawn beside them (a dashed
/// line, "compared" in the legend): `vlsyncd replay --compare`.
pub fn offset_svg_compared(
    title: &str,
    ests: &[Estimate],
    truth: Option<&[(Nanos, f64)]>,
    shaded: &[(Nanos, Nanos, String)],
    compared: &[Estimate],
) -> String {
    // values that cannot be placed (NaN, inf, beyond ±1e12 s) are left out
    let plottable = |ms: f64| ms.abs() <= MAX_PLOT_MS;
    let locked: Vec<&Estimate> = ests
        .iter()
        .filter(|e| {
            // as the compared run's: a lost estimate's offset is no estimate (σ of
            // hundreds of ms), drawn only as its state mark
            matches!(e.state, EstimatorState::Tracking | EstimatorState::Holding)
                && plottable(e.offset_s * 1e3)
        })
        .collect();
    // a run whose LiDAR clock restarted (a recording over a driver restart) goes
    // back in time: each stretch that does not is a line and a band of its own
    let mut stretches: Vec<&[&Estimate]> = Vec::new();
    let mut begin = 0;
    for i in 1..=locked.len() {
        if i == locked.len() || locked[i].t_ref_ns < locked[i - 1].t_ref_ns {
            stretches.push(&locked[begin..i]);
            begin = i;
        }
    }
    let truth: Vec<(Nanos, f64)> = truth
        .unwrap_or_default()
        .iter()
        .copied()
        .filter(|p| plottable(p.1 * 1e3))
        .collect();
    let compared: Vec<(Nanos, f64)> = compared
        .iter()
        .filter(|e| {
            matches!(e.state, EstimatorState::Tracking | EstimatorState::Holding)
                && plottable(e.offset_s * 1e3)
        })
        .map(|e| (e.t_ref_ns, e.offset_s))
        .collect();
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(s, r#"<rect width="{W}" height="{H}" fill="white"/>"#);
    let _ = writeln!(
        s,
        r#"<text x="{L}" y="20" font-size="14">{}</text>"#,
        xml(title)
    );
    if locked.is_empty() {
        let _ = writeln!(
            s,
            r#"<text x="{L}" y="{}">no locked estimate</text></svg>"#,
            H / 2.0
        );
        return s;
    }
    // the span of every estimate, whatever their order
    let t0 = nanos_to_secs(ests.iter().map(|e| e.t_ref_ns).min().unwrap_or(0));
    let t1 = nanos_to_secs(ests.iter().map(|e| e.t_ref_ns).max().unwrap_or(0)).max(t0 + 1.0);
    let mut ys: Vec<f64> = locked.iter().map(|e| e.offset_s * 1e3).collect();
    ys.extend(truth.iter().chain(&compared).map(|p| p.1 * 1e3));
    ys.sort_by(f64::total_cmp);
    // robust range: ignore the extreme 1 % so one wild estimate cannot flatten the plot
    let lo_i = ys.len() / 100;
    let hi_i = ys.len() - 1 - ys.len() / 100;
    let (mut y0, mut y1) = (ys[lo_i], ys[hi_i]);
    // at least 5 ms, and enough to stay a range at large magnitudes
    let pad = ((y1 - y0) * 0.15)
        .max(5.0)
        .max(y0.abs().max(y1.abs()) * 1e-6);
    y0 -= pad;
    y1 += pad;
    let px = |t: f64| L + (t - t0) / (t1 - t0) * (W - L - R);
    let py = |y: f64| T + (y1 - y.clamp(y0, y1)) / (y1 - y0) * (H - T - B);
    for (a, b, label) in shaded {
        // intervals reaching past the estimates are cut at the plot's edges
        let edge = |x: f64| x.clamp(L, W - R);
        let (xa, xb) = (edge(px(nanos_to_secs(*a))), edge(px(nanos_to_secs(*b))));
        if xb <= xa {
            continue;
        }
        let _ = writeln!(
            s,
            r##"<rect x="{xa:.1}" y="{T}" width="{:.1}" height="{}" fill="#ddf4ff"/><text x="{:.1}" y="{}" fill="#0969da">{}</text>"##,
            (xb - xa).max(0.5),
            H - T - B,
            xa + 2.0,
            T + 12.0,
            xml(label)
        );
    }
    // grid and axes
    let ts = tick_step(t1 - t0);
    // as many decimals as the step has (a 0.5 s step: 998.5, not 998)
    let decimals = (-ts.log10().floor()).clamp(0.0, 9.0) as usize;
    let first_t = (t0 / ts).ceil() * ts;
    for t in (0..=MAX_TICKS)
        .map(|i| first_t + f64::from(i) * ts)
        .take_while(|t| *t <= t1)
    {
        let x = px(t);
        let _ = writeln!(
            s,
            r##"<line x1="{x:.1}" y1="{T}" x2="{x:.1}" y2="{}" stroke="#eee"/><text x="{x:.1}" y="{}" text-anchor="middle">{t:.decimals$}</text>"##,
            H - B,
            H - B + 16.0
        );
    }
    let yst = tick_step(y1 - y0);
    let first_y = (y0 / yst).ceil() * yst;
    for y in (0..=MAX_TICKS)
        .map(|i| first_y + f64::from(i) * yst)
        .take_while(|y| *y <= y1)
    {
        let yy = py(y);
        let _ = writeln!(
            s,
            r##"<line x1="{L}" y1="{yy:.1}" x2="{}" y2="{yy:.1}" stroke="#eee"/><text x="{}" y="{:.1}" text-anchor="end">{y:.1}</text>"##,
            W - R,
            L - 6.0,
            yy + 4.0
        );
    }
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">LiDAR time (s)</text><text x="16" y="{}" transform="rotate(-90 16 {})" text-anchor="middle">offset t_L - t_C (ms)</text>"#,
        (L + W - R) / 2.0,
        H - 12.0,
        H / 2.0,
        H / 2.0
    );
    // ±2σ band (of the estimates whose σ is known), one per stretch
    for stretch in &stretches {
        let banded: Vec<&&Estimate> = stretch
            .iter()
            .filter(|e| plottable(e.offset_std_s * 2e3))
            .collect();
        let mut band = String::new();
        for e in &banded {
            let _ = write!(
                band,
                "{:.1},{:.1} ",
                px(nanos_to_secs(e.t_ref_ns)),
                py((e.offset_s + 2.0 * e.offset_std_s) * 1e3)
            );
        }
        for e in banded.iter().rev() {
            let _ = write!(
                band,
                "{:.1},{:.1} ",
                px(nanos_to_secs(e.t_ref_ns)),
                py((e.offset_s - 2.0 * e.offset_std_s) * 1e3)
            );
        }
        let _ = writeln!(
            s,
            r##"<polygon points="{band}" fill="#54aeff" fill-opacity="0.25"/>"##
        );
    }
    // raw measurements
    // raw measurements outside the plotted range are left out, not piled on the edge
    for e in ests
        .iter()
        .filter(|e| e.measured_offset_s.is_finite())
        .filter(|e| (y0..=y1).contains(&(e.measured_offset_s * 1e3)))
    {
        let _ = writeln!(
            s,
            r##"<circle cx="{:.1}" cy="{:.1}" r="1.5" fill="#999"/>"##,
            px(nanos_to_secs(e.t_ref_ns)),
            py(e.measured_offset_s * 1e3)
        );
    }
    // the truth and the compared run, each a line within the estimates' time span
    for (points, style) in [
        (&truth, r#"stroke="black" stroke-width="1.5""#),
        (
            &compared,
            r##"stroke="#8250df" stroke-width="1.5" stroke-dasharray="5 3""##,
        ),
    ] {
        if points.is_empty() {
            continue;
        }
        let pts: String = points
            .iter()
            .filter(|p| {
                let t = nanos_to_secs(p.0);
                t >= t0 && t <= t1
            })
            .map(|p| format!("{:.1},{:.1} ", px(nanos_to_secs(p.0)), py(p.1 * 1e3)))
            .collect();
        let _ = writeln!(s, r#"<polyline points="{pts}" fill="none" {style}/>"#);
    }
    for stretch in &stretches {
        let pts: String = stretch
            .iter()
            .map(|e| {
                format!(
                    "{:.1},{:.1} ",
                    px(nanos_to_secs(e.t_ref_ns)),
                    py(e.offset_s * 1e3)
                )
            })
            .collect();
        let _ = writeln!(
            s,
            r##"<polyline points="{pts}" fill="none" stroke="#0969da" stroke-width="1.5"/>"##
        );
    }
    for e in ests {
        let _ = writeln!(
            s,
            r#"<rect x="{:.1}" y="{}" width="2" height="6" fill="{}"/>"#,
            px(nanos_to_secs(e.t_ref_ns)),
            H - B + 22.0,
            color(e.state)
        );
    }
    // legend
    let lx = W - R - 330.0;
    let _ = writeln!(
        s,
        r##"<g transform="translate({lx},{})"><line x1="0" y1="0" x2="18" y2="0" stroke="#0969da" stroke-width="2"/><text x="22" y="4">estimate ±2σ</text><line x1="105" y1="0" x2="123" y2="0" stroke="black" stroke-width="2"/><text x="127" y="4">truth</text><circle cx="175" cy="0" r="2" fill="#999"/><text x="181" y="4">measured</text><rect x="245" y="-4" width="6" height="8" fill="#1a7f37"/><text x="254" y="4">tracking</text></g>"##,
        T - 10.0
    );
    if !compared.is_empty() {
        let _ = writeln!(
            s,
            r##"<g transform="translate({},{})"><line x1="0" y1="0" x2="18" y2="0" stroke="#8250df" stroke-width="2" stroke-dasharray="5 3"/><text x="22" y="4">compared</text></g>"##,
            lx - 90.0,
            T - 10.0
        );
    }
    let _ = writeln!(s, "</svg>");
    s
}

fn xml(t: &str) -> String {
    t.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;
    use vlsync_common::Polarity;

    fn est(t: f64, o: f64, st: EstimatorState) -> Estimate {
        Estimate {
            seq: 0,
            t_ref_ns: (t * 1e9) as i64,
            offset_s: o,
            drift: 0.0,
            offset_std_s: 0.002,
            drift_std: 0.0,
            state: st,
            polarity: Polarity::Negative,
            peak_score: 0.9,
            peak_ratio: 2.0,
            measured_offset_s: o + 0.001,
        }
    }

    #[test]
    fn plot_has_every_layer_and_escapes_the_title() {
        let ests: Vec<Estimate> = (0..50)
            .map(|i| {
                est(
                    i as f64,
                    0.1,
                    if i < 3 {
                        EstimatorState::Acquiring
                    } else {
                        EstimatorState::Tracking
                    },
                )
            })
            .collect();
        let truth: Vec<(Nanos, f64)> = (0..50).map(|i| (i * 1_000_000_000, 0.1)).collect();
        let svg = offset_svg(
            "a<b & c",
            &ests,
            Some(&truth),
            &[(10_000_000_000, 20_000_000_000, "load".into())],
        );
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert!(svg.contains("a&lt;b &amp; c"));
        assert!(
            svg.contains("<polygon") && svg.contains("stroke=\"black\"") && svg.contains(">load<")
        );
        // shading past the data is cut at the edge; wholly outside it is left out
        let svg = offset_svg(
            "t",
            &ests,
            None,
            &[
                (40_000_000_000, 90_000_000_000, "late".into()),
                (60_000_000_000, 90_000_000_000, "outside".into()),
            ],
        );
        assert!(svg.contains(">late<") && !svg.contains(">outside<"));
        let x = |tag: &str| -> f64 {
            let i = svg.find(&format!(">{tag}<")).unwrap();
            let r = svg[..i].rfind("<rect x=\"").unwrap();
            let rest = &svg[r + 9..];
            let xa: f64 = rest[..rest.find('"').unwrap()].parse().unwrap();
            let w = &rest[rest.find("width=\"").unwrap() + 7..];
            xa + w[..w.find('"').unwrap()].parse::<f64>().unwrap()
        };
        assert!(x("late") <= W - R + 0.05);
        // 50 measurements plus the legend's marker
        assert_eq!(svg.matches("<circle").count(), 50 + 1);
    }

    #[test]
    fn a_clock_that_restarts_gives_two_lines_on_the_canvas_and_lost_is_no_line() {
        // a recording over a driver restart: the second session's stamps start again
        // near 0, after a first at 998-1000 s
        let mut ests: Vec<Estimate> = (0..20)
            .map(|i| est(998.0 + 0.1 * i as f64, 0.1, EstimatorState::Tracking))
            .collect();
        ests.extend((0..20).map(|i| est(0.1 * i as f64, 0.2, EstimatorState::Tracking)));
        ests.push(est(2.5, -0.4, EstimatorState::Lost));
        let svg = offset_svg("t", &ests, None, &[]);
        let lines: Vec<&str> = svg
            .lines()
            .filter(|l| l.starts_with("<polyline") && l.contains("#0969da"))
            .collect();
        assert_eq!(lines.len(), 2, "{svg}");
        assert_eq!(svg.matches("<polygon").count(), 2);
        for l in &lines {
            let pts = &l[l.find("points=\"").unwrap() + 8..];
            let pts = &pts[..pts.find('"').unwrap()];
            assert_eq!(
                pts.split_whitespace().count(),
                20,
                "the lost one is no point"
            );
            for p in pts.split_whitespace() {
                let x: f64 = p.split(',').next().unwrap().parse().unwrap();
                assert!((L - 0.05..=W - R + 0.05).contains(&x), "{x} off the canvas");
            }
        }
        // a span of 2 s: ticks of 0.2 s, labelled with their decimal
        let short: Vec<Estimate> = (0..21)
            .map(|i| est(998.0 + 0.1 * i as f64, 0.1, EstimatorState::Tracking))
            .collect();
        let svg = offset_svg("t", &short, None, &[]);
        assert!(
            svg.contains(">998.2</text>") && svg.contains(">999.0</text>"),
            "{svg}"
        );
    }

    #[test]
    fn non_finite_and_huge_values_are_left_out() {
        let ests: Vec<Estimate> = (0..20)
            .map(|i| est(i as f64, 0.1, EstimatorState::Tracking))
            .collect();
        let nan_truth: Vec<(Nanos, f64)> = (0..4).map(|i| (i * 40_000_000_000, f64::NAN)).collect();
        let mut odd = ests.clone();
        odd[3].offset_std_s = f64::NAN;
        odd[4].offset_s = f64::INFINITY;
        odd[5].offset_s = 1e300;
        odd[6].measured_offset_s = f64::NEG_INFINITY;
        let mixed = [
            (0, f64::INFINITY),
            (1_000_000_000, 0.1),
            (2_000_000_000, -1e300),
        ];
        for (e, tr) in [
            (&ests, &nan_truth[..]),
            (&odd, &mixed[..]),
            (&odd, &nan_truth[..]),
        ] {
            let svg = offset_svg("t", e, Some(tr), &[]);
            assert!(svg.trim_end().ends_with("</svg>"));
            assert!(!svg.contains("NaN") && !svg.contains("inf"), "{svg}");
        }
        // nothing plottable at all
        let svg = offset_svg("t", &odd[4..6], Some(&nan_truth), &[]);
        assert!(svg.contains("no locked estimate"));
        // large but plottable offsets with a tiny spread still give a finite range
        let far: Vec<Estimate> = (0..20)
            .map(|i| est(i as f64, 1e11 + 1e-3 * i as f64, EstimatorState::Tracking))
            .collect();
        let svg = offset_svg("t", &far, None, &[]);
        assert!(!svg.contains("NaN") && svg.matches("<line").count() < 300);
    }

    #[test]
    fn a_compared_run_is_a_dashed_line_with_its_legend_entry() {
        let ests: Vec<Estimate> = (0..20)
            .map(|i| est(i as f64, 0.1, EstimatorState::Tracking))
            .collect();
        let plain = offset_svg("t", &ests, None, &[]);
        assert!(!plain.contains("stroke-dasharray") && !plain.contains(">compared<"));
        let mut other = ests.clone();
        other[0].state = EstimatorState::Acquiring;
        other[1].offset_s = f64::NAN;
        let svg = offset_svg_compared("t", &ests, None, &[], &other);
        assert_eq!(svg.matches(">compared<").count(), 1);
        let line = svg
            .lines()
            .find(|l| l.starts_with("<polyline") && l.contains("stroke-dasharray"))
            .expect("the compared line");
        // its locked, plottable estimates only: 18 points
        let pts = &line[line.find("points=\"").unwrap() + 8..];
        assert_eq!(pts[..pts.find('"').unwrap()].split_whitespace().count(), 18);
    }

    #[test]
    fn empty_input_says_so() {
        let svg = offset_svg("x", &[], None, &[]);
        assert!(svg.contains("no locked estimate"));
    }
}
