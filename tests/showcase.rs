//! The showcase page (issue 29): `vellum showcase` on the shipped chest CT, as `make run` runs it,
//! writes index.html; every image and link on it exists; headless Chromium (Debian's `chromium`,
//! which `make test` installs) loads every image (naturalWidth > 0) with the composed picture
//! among them, and takes a screenshot of the page (target/showcase-screenshot.png, to look at).
//! Each command of the page runs with validation on: a validation message fails the showcase.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every `src="..."` and `href="..."` target of a page that is not an anchor.
fn targets(html: &str) -> Vec<String> {
    let mut found = Vec::new();
    for key in ["src=\"", "href=\""] {
        let mut rest = html;
        while let Some(i) = rest.find(key) {
            rest = &rest[i + key.len()..];
            let end = rest.find('"').expect("a closing quote");
            if !rest[..end].starts_with('#') {
                found.push(rest[..end].to_string());
            }
            rest = &rest[end..];
        }
    }
    found
}

/// Debian's Chromium, or `None` (a failure under CI, where `make test` installs it).
fn chromium() -> Option<&'static str> {
    let found = ["chromium", "chromium-browser"].into_iter().find(|c| {
        Command::new(c)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    });
    if found.is_none() {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "chromium is missing: `make test` installs it (apt package chromium)"
        );
        eprintln!("SKIPPED the browser checks: chromium is not installed (make test installs it)");
    }
    found
}

fn headless(browser: &str, args: &[&str]) -> std::process::Output {
    Command::new(browser)
        .args([
            "--headless=new",
            "--no-sandbox",
            "--disable-gpu",
            "--allow-file-access-from-files",
        ])
        .args(args)
        .output()
        .expect("run chromium")
}

/// A page beside index.html that loads it in a frame and writes, once it has loaded, each image's
/// src and naturalWidth into its own DOM, which `--dump-dom` prints.
const CHECKER: &str = r#"<!DOCTYPE html><html><body><pre id="result">pending</pre>
<iframe id="page" src="index.html" style="width:1600px;height:900px"></iframe>
<script>
document.getElementById('page').addEventListener('load', function () {
  var images = Array.from(this.contentDocument.images);
  document.getElementById('result').textContent =
    JSON.stringify(images.map(function (i) { return [i.getAttribute('src'), i.naturalWidth]; }));
});
</script></body></html>"#;

#[test]
fn the_showcase_page_shows_every_image() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = Command::new(env!("CARGO_BIN_EXE_vellum"))
        .args([
            "showcase",
            "data/ct_chest/ct_chest.nhdr",
            "--iso",
            "150",
            "--out",
        ])
        .arg(&out)
        .current_dir(repo())
        .env("VELLUM_VALIDATION", "1")
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let index = out.join("index.html");
    let html = std::fs::read_to_string(&index).unwrap();
    let links = targets(&html);
    assert!(links.len() >= 20, "{links:?}");
    for t in &links {
        assert!(!t.contains("://"), "the page fetches {t}");
        assert!(
            out.join(t).is_file(),
            "the page links {t}, which is not there"
        );
    }
    assert!(
        html.contains("<img src=\"composed.png\""),
        "the composed picture is on the page"
    );

    let Some(browser) = chromium() else { return };
    std::fs::write(out.join("check.html"), CHECKER).unwrap();
    let url = |p: &Path| format!("file://{}", p.display());
    let dom = headless(
        browser,
        &[
            "--virtual-time-budget=20000",
            "--dump-dom",
            &url(&out.join("check.html")),
        ],
    );
    let dom = String::from_utf8_lossy(&dom.stdout);
    let json = dom
        .split("<pre id=\"result\">")
        .nth(1)
        .and_then(|r| r.split("</pre>").next())
        .unwrap_or("")
        .replace("&quot;", "\"");
    let images: Vec<(String, u64)> =
        serde_json::from_str(&json).unwrap_or_else(|e| panic!("{e}: the checker said {json:?}"));
    assert_eq!(images.len(), html.matches("<img ").count(), "{images:?}");
    for (src, width) in &images {
        assert!(*width > 0, "{src} did not load in Chromium");
    }
    assert!(images.iter().any(|(s, w)| s == "composed.png" && *w >= 768));

    let shot = repo().join("target/showcase-screenshot.png");
    let _ = std::fs::remove_file(&shot);
    let taken = headless(
        browser,
        &[
            "--hide-scrollbars",
            "--window-size=1600,4000",
            &format!("--screenshot={}", shot.display()),
            &url(&index),
        ],
    );
    assert!(
        taken.status.success(),
        "{}",
        String::from_utf8_lossy(&taken.stderr)
    );
    let png = image::open(&shot).expect("the screenshot").to_rgb8();
    assert_eq!(png.dimensions(), (1600, 4000));
    // Not blank: the composed picture's dark frame and the page's light background are both there.
    let dark = png.pixels().filter(|p| p.0.iter().all(|&c| c < 20)).count();
    let light = png
        .pixels()
        .filter(|p| p.0.iter().all(|&c| c > 230))
        .count();
    assert!(
        dark > 100_000 && light > 100_000,
        "dark {dark}, light {light}"
    );
    eprintln!("screenshot of the page: {}", shot.display());
}

/// A missing manifest, and a command of the manifest that fails, each end the showcase with one
/// sentence and no page.
#[test]
fn a_failing_showcase_says_where_and_writes_no_page() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let out_s = out.to_str().unwrap();
    let o = common::vellum(&[
        "showcase",
        "x.nhdr",
        "--iso",
        "1",
        "--out",
        out_s,
        "--manifest",
        "/no/such.json",
    ]);
    common::fails_with(&o, "the showcase manifest /no/such.json cannot be read");
    let manifest = dir.path().join("m.json");
    std::fs::write(
        &manifest,
        r#"{"title": "t", "intro": "i", "sections": [{"id": "a", "title": "A", "sentence": "s",
            "runs": [{"args": ["info", "{input}"]}]}]}"#,
    )
    .unwrap();
    let missing = dir.path().join("missing.nhdr");
    let o = common::vellum(&[
        "showcase",
        missing.to_str().unwrap(),
        "--iso",
        "1",
        "--out",
        out_s,
        "--manifest",
        manifest.to_str().unwrap(),
    ]);
    common::fails_with_all(
        &o,
        &["the showcase stopped at `vellum info", "missing.nhdr"],
    );
    assert!(!out.join("index.html").exists(), "no page after a failure");
}
