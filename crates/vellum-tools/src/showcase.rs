//! The showcase page (`vellum showcase`, what `make run` ends with): one offline HTML page that
//! shows the four techniques composed in one picture, then each technique on its own, with the
//! exact command that made every image and its GPU timings.
//!
//! What the page holds comes from a manifest (`examples/showcase.json`): sections of runs, each a
//! `vellum` command line with placeholders, the images it writes and a caption for each, and the
//! other files it writes. The binary runs every command (as a child process of itself, with
//! `--json`), gathers each one's pass timings, and this module writes the page. The page links
//! only files the runs wrote, by relative paths, and fetches nothing.

use serde::Deserialize;
use std::fmt::Write;
use vellum_error::{Error, Result};

/// The manifest: the composed picture first, then one section per technique.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub title: String,
    /// One or two sentences under the title.
    pub intro: String,
    /// The sections, in page order; the first is shown as the composed picture at the top.
    pub sections: Vec<Section>,
}

/// A section of the page.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Section {
    /// Anchor name, unique in the page.
    pub id: String,
    pub title: String,
    /// The paper the technique comes from, as cited.
    #[serde(default)]
    pub paper: String,
    /// What the images show, in one sentence.
    pub sentence: String,
    pub runs: Vec<Run>,
}

/// One `vellum` command and what it writes.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Run {
    /// The arguments after `vellum`. `{input}`, `{iso}` and `{out}` are replaced by the
    /// showcase's input, isovalue and output folder.
    pub args: Vec<String>,
    /// Images written, relative to the output folder.
    #[serde(default)]
    pub images: Vec<Image>,
    /// Other files written (volumes, tables, SVG, scene files), linked from the page.
    #[serde(default)]
    pub files: Vec<String>,
    /// Whether the command takes `--json` (its passes' timings then come back); default true.
    #[serde(default = "yes")]
    pub json: bool,
    /// Outputs of an earlier showcase removed before the run, relative to the output folder:
    /// a store folder that `convert` would refuse to overwrite, a feature map `migrate` would
    /// append to.
    #[serde(default)]
    pub replaces: Vec<String>,
}

fn yes() -> bool {
    true
}

/// An image a run writes, and its caption.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Image {
    pub file: String,
    pub caption: String,
    /// Width to show it at in CSS pixels, when not its own (slices of a few hundred voxels
    /// shown larger); a run with such an image spans the page.
    #[serde(default)]
    pub width: Option<u32>,
}

/// What the placeholders of a manifest stand for.
pub struct Vars<'a> {
    pub input: &'a str,
    pub iso: &'a str,
    pub out: &'a str,
}

impl Run {
    /// The arguments with the placeholders replaced.
    pub fn expand(&self, vars: &Vars) -> Vec<String> {
        self.args
            .iter()
            .map(|a| {
                a.replace("{input}", vars.input)
                    .replace("{iso}", vars.iso)
                    .replace("{out}", vars.out)
            })
            .collect()
    }

    /// Every file the run writes, relative to the output folder.
    pub fn outputs(&self) -> impl Iterator<Item = &str> {
        self.images
            .iter()
            .map(|i| i.file.as_str())
            .chain(self.files.iter().map(String::as_str))
    }
}

impl Manifest {
    /// Parses and checks a manifest: at least one section, each with a run; unique anchors;
    /// output names that stay inside the output folder.
    pub fn from_json_str(json: &str) -> Result<Self> {
        let m: Manifest = serde_json::from_str(json)
            .map_err(|e| Error::Invalid(format!("the showcase manifest is not valid: {e}")))?;
        if m.sections.is_empty() || m.sections.iter().any(|s| s.runs.is_empty()) {
            return Err(Error::Invalid(
                "the showcase manifest needs at least one section, each with at least one run"
                    .into(),
            ));
        }
        let mut ids: Vec<&str> = m.sections.iter().map(|s| s.id.as_str()).collect();
        ids.sort_unstable();
        if ids.windows(2).any(|w| w[0] == w[1]) {
            return Err(Error::Invalid(
                "the showcase manifest repeats a section id; expected unique ids".into(),
            ));
        }
        let runs = m.sections.iter().flat_map(|s| &s.runs);
        let replaced = runs
            .clone()
            .flat_map(|r| r.replaces.iter().map(String::as_str));
        for file in runs.flat_map(Run::outputs).chain(replaced) {
            let p = std::path::Path::new(file);
            if p.is_absolute() || p.components().any(|c| c.as_os_str() == "..") {
                return Err(Error::Invalid(format!(
                    "the showcase manifest names the output {file:?}; expected a name inside the output folder"
                )));
            }
        }
        Ok(m)
    }
}

/// What one run reported: its command line as shown, and its passes' times in ms.
#[derive(Clone, Debug, Default)]
pub struct Outcome {
    pub command: String,
    pub passes: Vec<(String, f64)>,
    /// Wall-clock seconds of the whole command (start-up, reading, writing included).
    pub seconds: f64,
}

impl Outcome {
    /// The passes of a command's `--json` report (its text): its `passes` object, in the
    /// report's order, which is the order the passes ran in (`serde_json` with
    /// `preserve_order`).
    pub fn passes_of(report: &str) -> Vec<(String, f64)> {
        Self::passes_in(&serde_json::from_str(report).unwrap_or_default())
    }

    /// [`Outcome::passes_of`] for a report already parsed.
    pub fn passes_in(report: &serde_json::Value) -> Vec<(String, f64)> {
        report["passes"]
            .as_object()
            .map(|o| {
                o.iter()
                    .filter_map(|(k, v)| v.as_f64().map(|ms| (k.clone(), ms)))
                    .collect()
            })
            .unwrap_or_default()
    }
}

/// HTML text with `&`, `<`, `>` and `"` escaped.
fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

const STYLE: &str = "body{font-family:system-ui,sans-serif;max-width:2000px;margin:2em auto;padding:0 1em;background:#fafafa;color:#222}\
h1{margin-bottom:.2em}nav a{margin-right:1em}section{margin:2.5em 0}\
.run{display:inline-block;vertical-align:top;width:520px;max-width:100%;margin:0 1.2em 1.5em 0}.run.wide{width:auto;display:block}\
figure{margin:0 0 .4em}figure img{max-width:100%;height:auto;background:#000}\
figcaption{font-size:.9em;color:#444}pre{background:#eee;padding:.5em;white-space:pre-wrap;word-break:break-all;font-size:.8em}\
table{border-collapse:collapse;font-size:.8em}td,th{padding:0 .8em;text-align:right}td:first-child,th:first-child{text-align:left}\
details summary{cursor:pointer;font-size:.85em;color:#444}.meta{color:#666;font-size:.9em}";

/// The page: the first section as the composed picture, then the others, each with its images,
/// commands and timings. `device` names the GPU the timings come from.
pub fn html(m: &Manifest, outcomes: &[Vec<Outcome>], device: &str) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>{STYLE}</style></head><body>\n",
        escape(&m.title)
    );
    let _ = writeln!(
        h,
        "<h1>{}</h1>\n<p>{}</p>",
        escape(&m.title),
        escape(&m.intro)
    );
    let _ = writeln!(
        h,
        "<p class=\"meta\">Made by <code>vellum showcase</code> (vellum {}) on {}. Times are milliseconds per pass as each command reports them (GPU timestamps; passes marked (cpu) ran on the host), and wall-clock seconds per command.</p>",
        env!("CARGO_PKG_VERSION"),
        escape(device)
    );
    h.push_str("<nav>");
    for s in &m.sections {
        let _ = write!(h, "<a href=\"#{}\">{}</a>", escape(&s.id), escape(&s.title));
    }
    h.push_str("</nav>\n");
    for (s, runs) in m.sections.iter().zip(outcomes) {
        section(&mut h, s, runs);
    }
    h.push_str("</body></html>\n");
    h
}

fn section(h: &mut String, s: &Section, outcomes: &[Outcome]) {
    let _ = writeln!(
        h,
        "<section id=\"{}\"><h2>{}</h2>",
        escape(&s.id),
        escape(&s.title)
    );
    if !s.paper.is_empty() {
        let _ = writeln!(h, "<p class=\"meta\">{}</p>", escape(&s.paper));
    }
    let _ = writeln!(h, "<p>{}</p>", escape(&s.sentence));
    for (run, outcome) in s.runs.iter().zip(outcomes) {
        // The only run of a section, or one with an image shown at its own width, spans the page.
        let wide = s.runs.len() == 1 || run.images.iter().any(|i| i.width.is_some());
        let _ = writeln!(h, "<div class=\"run{}\">", if wide { " wide" } else { "" });
        for img in &run.images {
            let width = img
                .width
                .map_or(String::new(), |w| format!(" width=\"{w}\""));
            let _ = writeln!(
                h,
                "<figure><img src=\"{0}\" alt=\"{1}\"{width}><figcaption>{1} (<a href=\"{0}\">{0}</a>)</figcaption></figure>",
                escape(&img.file),
                escape(&img.caption)
            );
        }
        let _ = writeln!(h, "<pre><code>{}</code></pre>", escape(&outcome.command));
        if !run.files.is_empty() {
            h.push_str("<p>Also wrote: ");
            let links: Vec<String> = run
                .files
                .iter()
                .map(|f| format!("<a href=\"{0}\">{0}</a>", escape(f)))
                .collect();
            h.push_str(&links.join(", "));
            h.push_str("</p>\n");
        }
        timings(h, outcome);
        h.push_str("</div>\n");
    }
    h.push_str("</section>\n");
}

fn timings(h: &mut String, o: &Outcome) {
    let mut rows = String::new();
    for (name, ms) in &o.passes {
        let _ = write!(rows, "<tr><td>{}</td><td>{ms:.2}</td></tr>", escape(name));
    }
    if o.passes.is_empty() {
        let _ = writeln!(
            h,
            "<p class=\"meta\">The whole command: {:.1} s (it reports no passes).</p>",
            o.seconds
        );
        return;
    }
    let gpu: f64 = o.passes.iter().map(|p| p.1).sum();
    let _ = writeln!(
        h,
        "<details open><summary>{} passes, {gpu:.0} ms; the whole command {:.1} s</summary><table><tr><th>pass</th><th>ms</th></tr>{rows}</table></details>",
        o.passes.len(),
        o.seconds
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    const MANIFEST: &str = r#"{
      "title": "t", "intro": "i",
      "sections": [
        {"id": "a", "title": "A <1>", "sentence": "s", "runs": [
          {"args": ["render", "{input}", "--iso", "{iso}", "--out", "{out}/a.png"],
           "images": [{"file": "a.png", "caption": "c & d"}], "files": ["a.nrrd"]}]}
      ]}"#;

    #[test]
    fn runs_expand_and_the_page_links_what_they_write() {
        let m = Manifest::from_json_str(MANIFEST).unwrap();
        let run = &m.sections[0].runs[0];
        let vars = Vars {
            input: "x.nhdr",
            iso: "150",
            out: "out",
        };
        assert_eq!(
            run.expand(&vars),
            ["render", "x.nhdr", "--iso", "150", "--out", "out/a.png"]
        );
        assert_eq!(run.outputs().collect::<Vec<_>>(), ["a.png", "a.nrrd"]);
        let outcome = Outcome {
            command: "vellum render x.nhdr".into(),
            passes: vec![("focus".into(), 1.5)],
            seconds: 0.25,
        };
        let page = html(&m, &[vec![outcome]], "llvmpipe");
        assert!(page.contains("<img src=\"a.png\" alt=\"c &amp; d\">"));
        assert!(page.contains("<a href=\"a.nrrd\">a.nrrd</a>"));
        assert!(page.contains("A &lt;1&gt;"));
        assert!(page.contains("<td>focus</td><td>1.50</td>"));
        assert!(!page.contains("http"), "the page fetches nothing");
        let report = r#"{"device": "d", "passes": {"upload": 1.0, "focus": 2.5, "context": 3}}"#;
        let names: Vec<String> = Outcome::passes_of(report)
            .into_iter()
            .map(|p| p.0)
            .collect();
        assert_eq!(
            names,
            ["upload", "focus", "context"],
            "in the order they ran"
        );
        assert!(Outcome::passes_of("not json").is_empty());
    }

    #[test]
    fn bad_manifests_are_refused() {
        let bad = MANIFEST.replace("a.nrrd", "../a.nrrd");
        assert!(Manifest::from_json_str(&bad).is_err());
        assert!(Manifest::from_json_str(r#"{"title":"t","intro":"i","sections":[]}"#).is_err());
        assert!(Manifest::from_json_str("{").is_err());
    }
}
