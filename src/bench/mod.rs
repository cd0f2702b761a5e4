//! Benchmarks behind `vellum bench`. Figures are GPU timestamps per pass, set beside a plain copy
//! of the same bytes and a CPU peer measured in the same run; no test depends on them.

pub mod render;
pub mod table1;

/// Median of `xs` (0 for an empty slice).
pub fn median(xs: &[f64]) -> f64 {
    let mut v: Vec<f64> = xs.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Where the shared data is: `VELLUM_DATA` when set (a machine where the binary runs away from
/// its checkout), else ../shared/data beside the checkout, if present.
pub fn shared_data() -> Option<std::path::PathBuf> {
    if let Some(p) = std::env::var_os("VELLUM_DATA") {
        let p = std::path::PathBuf::from(p);
        return p.is_dir().then_some(p);
    }
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    p.is_dir().then_some(p)
}
