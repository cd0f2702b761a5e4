//! The first five minutes (issue 29): what a newcomer meets with no flags.
//! - `render` of a real CT with no transfer function lights the content: its mean luminance is
//!   well above the plain grey ramp's (the default is the `auto` window from the histogram);
//! - a volume with no orientation is said to keep its axes, once, on stderr;
//! - a long command shows progress on a terminal and nothing when piped;
//! - the shipped scan is where the README says;
//! - the README's Rust example is examples/render_png.rs, word for word (the library's doctest
//!   runs that file).

mod common;

use std::path::{Path, PathBuf};

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// The shipped chest CT (LIDC-IDRI, data/ct_chest/SOURCE.md).
fn chest() -> String {
    repo("data/ct_chest/ct_chest.nhdr")
        .to_string_lossy()
        .into_owned()
}

/// Mean Rec. 709 luminance of the pixels that show something (any channel above 0).
fn content_luminance(png: &Path) -> f64 {
    let img = image::open(png).unwrap().to_rgb8();
    let lit: Vec<f64> = img
        .pixels()
        .filter(|p| p.0.iter().any(|&c| c > 0))
        .map(|p| {
            let [r, g, b] = p.0.map(|c| c as f64 / 255.0);
            0.2126 * r + 0.7152 * g + 0.0722 * b
        })
        .collect();
    assert!(lit.len() > 100, "{} shows almost nothing", png.display());
    lit.iter().sum::<f64>() / lit.len() as f64
}

#[test]
fn default_transfer_function_lights_a_real_ct() {
    let dir = tempfile::tempdir().unwrap();
    let render = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let chest = chest();
        let mut args = vec!["render", chest.as_str(), "--size", "128x128"];
        args.extend_from_slice(extra);
        args.extend(["--out", out.to_str().unwrap()]);
        let o = common::vellum(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        content_luminance(&out)
    };
    let (grey, auto) = (
        render("grey.png", &["--tf", "grey"]),
        render("auto.png", &[]),
    );
    eprintln!("chest CT content luminance: grey ramp {grey:.3}, default {auto:.3}");
    assert!(
        auto > 1.6 * grey,
        "default {auto:.3} against grey {grey:.3}"
    );
}

#[test]
fn unknown_orientation_is_said_once() {
    let dir = tempfile::tempdir().unwrap();
    // A raw file has no orientation.
    let raw = dir.path().join("v.raw");
    std::fs::write(&raw, vec![7u8; 16 * 16 * 16]).unwrap();
    let raw = raw.to_string_lossy().into_owned();
    let flags = ["--raw-dims", "16,16,16", "--raw-type", "u8"];
    let png = dir.path().join("v.png").to_string_lossy().into_owned();
    let mut args = vec![
        "render",
        raw.as_str(),
        "--size",
        "32x32",
        "--out",
        png.as_str(),
    ];
    args.extend(flags);
    let o = common::vellum(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(
        stderr.matches("axes are kept as stored").count(),
        1,
        "{stderr}"
    );
    let mut args = vec!["info", raw.as_str()];
    args.extend(flags);
    let o = common::vellum(&args);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert_eq!(
        stdout.matches("axes are kept as stored").count(),
        1,
        "{stdout}"
    );
    // An oriented volume says nothing of the kind.
    let o = common::vellum(&["render", &chest(), "--size", "32x32", "--out", &png]);
    assert!(!String::from_utf8_lossy(&o.stderr).contains("kept as stored"));
}

#[test]
fn progress_shows_on_a_terminal_only() {
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("p.png").to_string_lossy().into_owned();
    let command = format!(
        "{} render {} --size 256x256 --out {png}",
        env!("CARGO_BIN_EXE_vellum"),
        chest()
    );
    // Piped: nothing on stderr.
    let piped = std::process::Command::new("sh")
        .args(["-c", &command])
        .env("VELLUM_VALIDATION", "1")
        .output()
        .unwrap();
    assert!(piped.status.success());
    assert!(
        piped.stderr.is_empty(),
        "{}",
        String::from_utf8_lossy(&piped.stderr)
    );
    // On a terminal (util-linux `script` gives the command a pseudo-terminal): the spinner.
    let tty = std::process::Command::new("script")
        .args(["-qec", &command, "/dev/null"])
        .env("VELLUM_VALIDATION", "1")
        .output()
        .expect("util-linux script");
    assert!(
        tty.status.success(),
        "{}",
        String::from_utf8_lossy(&tty.stdout)
    );
    let shown = String::from_utf8_lossy(&tty.stdout);
    assert!(shown.contains("vellum: working"), "{shown}");
}

#[test]
fn the_shipped_scan_and_its_licence_are_there() {
    for f in [
        "data/ct_chest/ct_chest.nhdr",
        "data/ct_chest/ct_chest_256x256x133_uint8.raw.gz",
        "data/ct_chest/SOURCE.md",
    ] {
        assert!(repo(f).is_file(), "{f}");
    }
    let total: u64 = std::fs::read_dir(repo("data/ct_chest"))
        .unwrap()
        .map(|e| e.unwrap().metadata().unwrap().len())
        .sum();
    assert!(
        total <= 4 << 20,
        "data/ is {total} bytes; the issue allows 4 MB"
    );
    let source = std::fs::read_to_string(repo("data/ct_chest/SOURCE.md")).unwrap();
    assert!(source.contains("CC BY 3.0") && source.contains("doi:10.7937/K9/TCIA.2015.LO9QL9SX"));
}

#[test]
fn the_readme_shows_the_rust_example_that_the_doctest_runs() {
    let readme = std::fs::read_to_string(repo("README.md")).unwrap();
    let example = std::fs::read_to_string(repo("examples/render_png.rs")).unwrap();
    assert!(example.contains("Session::open") && example.contains("write_png_rgb"));
    assert!(
        readme.contains(&format!("```rust\n{example}```")),
        "README.md's Rust example differs from examples/render_png.rs"
    );
    let lib = std::fs::read_to_string(repo("src/lib.rs")).unwrap();
    assert!(lib.contains("include_str!(\"../examples/render_png.rs\")"));
}
