//! Benchmarks behind `vellum bench`. Figures are GPU timestamps per pass, set beside a plain copy
//! of the same bytes and a CPU peer measured in the same run; no test depends on them.

pub mod lines;
pub mod occlusion;
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
    let p = workspace().join("../shared/data");
    p.is_dir().then_some(p)
}

/// The checkout this crate was built in (its workspace root, two folders above the crate).
fn workspace() -> &'static std::path::Path {
    std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
}

/// The peer script `benches/<script>` of the checkout the binary was built in, or, when the binary
/// runs away from it (on a lent GPU machine, beside a copy of the working tree), of the current
/// folder.
pub fn peer_script(script: &str) -> std::path::PathBuf {
    let built = workspace().join("benches").join(script);
    if built.is_file() {
        built
    } else {
        std::path::Path::new("benches").join(script)
    }
}

/// Runs the peer script `benches/<script>` with python3 and `args`, and parses its stdout as JSON;
/// `None`, with a warning, when python3, the script or its libraries fail.
pub fn python_peer(script: &str, args: &[std::ffi::OsString]) -> Option<serde_json::Value> {
    match std::process::Command::new("python3")
        .arg(peer_script(script))
        .args(args)
        .output()
    {
        Ok(o) if o.status.success() => serde_json::from_slice(&o.stdout).ok(),
        Ok(o) => {
            log::warn!(
                "{script} failed: {}",
                String::from_utf8_lossy(&o.stderr).trim()
            );
            None
        }
        Err(e) => {
            log::warn!("{script} could not run python3: {e}");
            None
        }
    }
}
