//! The layers of ARCHITECTURE.md, read off the source: every `crate::…` path outside comments
//! (in `use` lines and inline) is an import of that module. Asserts that src/render/'s file-level
//! import graph has no cycle and that no layer reaches above itself.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn rust_files(dir: &Path) -> Vec<PathBuf> {
    let mut pending = vec![dir.to_path_buf()];
    let mut files = Vec::new();
    while let Some(dir) = pending.pop() {
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                pending.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") {
                files.push(path);
            }
        }
    }
    files
}

/// The source without comment lines.
fn code(path: &Path) -> String {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter(|l| !l.trim_start().starts_with("//"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// The names that follow each `prefix` in `text` (`crate::render::` → `slicer`, `view`, …).
fn after(text: &str, prefix: &str) -> BTreeSet<String> {
    text.match_indices(prefix)
        .filter(|(i, _)| {
            // Not the tail of a longer path such as `vellum::crate::` or `my_crate::`.
            text[..*i]
                .chars()
                .next_back()
                .is_none_or(|c| !(c.is_alphanumeric() || c == '_' || c == ':'))
        })
        .map(|(i, _)| {
            text[i + prefix.len()..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect()
        })
        .filter(|s: &String| !s.is_empty())
        .collect()
}

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// The file-level graph of src/render/: module → the render modules it names.
fn render_graph() -> BTreeMap<String, BTreeSet<String>> {
    let dir = src().join("render");
    let mut graph = BTreeMap::new();
    for path in rust_files(&dir) {
        let rel = path.strip_prefix(&dir).unwrap();
        let first = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = first.trim_end_matches(".rs").to_string();
        let mut uses = after(&code(&path), "crate::render::");
        uses.remove(&module);
        graph
            .entry(module)
            .or_insert_with(BTreeSet::new)
            .extend(uses);
    }
    graph
}

/// A cycle of `graph` as the path that closes it, if there is one.
fn cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        path.push(node.to_string());
        match state.get(node) {
            Some(1) => return Some(path.clone()),
            Some(2) => {
                path.pop();
                return None;
            }
            _ => {}
        }
        state.insert(node.to_string(), 1);
        for next in graph.get(node).into_iter().flatten() {
            if let Some(c) = visit(next, graph, state, path) {
                return Some(c);
            }
        }
        state.insert(node.to_string(), 2);
        path.pop();
        None
    }
    let mut state = BTreeMap::new();
    graph
        .keys()
        .find_map(|n| visit(n, graph, &mut state, &mut Vec::new()))
}

#[test]
fn the_render_modules_import_each_other_without_a_cycle() {
    let graph = render_graph();
    for m in [
        "frame", "view", "shading", "slicer", "raycast", "post", "targets",
    ] {
        assert!(graph.contains_key(m), "src/render/{m}.rs is read");
    }
    assert!(graph["frame"].contains("slicer") && graph["frame"].contains("raycast"));
    assert_eq!(
        cycle(&graph),
        None,
        "the import graph of src/render/: {graph:#?}"
    );
    // The checker finds a cycle where there is one.
    let mut looped = graph.clone();
    looped.get_mut("view").unwrap().insert("frame".into());
    assert!(cycle(&looped).is_some());
}

/// Each layer and the modules it must never import (ARCHITECTURE.md).
const FORBIDDEN: [(&str, &[&str]); 7] = [
    (
        "volume",
        &[
            "gpu", "passes", "classify", "render", "viewer", "bench", "ash",
        ],
    ),
    (
        "gpu",
        &[
            "volume", "passes", "classify", "render", "viewer", "bench", "imaging",
        ],
    ),
    ("imaging", &["gpu", "passes", "render", "viewer", "ash"]),
    ("classify", &["passes", "render", "viewer", "bench"]),
    ("passes", &["render", "viewer", "bench", "figures"]),
    ("render", &["viewer", "bench", "figures"]),
    ("viewer", &["bench", "figures"]),
];

#[test]
fn no_layer_imports_one_above_it() {
    let mut checked = 0;
    for (layer, forbidden) in FORBIDDEN {
        let files = rust_files(&src().join(layer));
        assert!(!files.is_empty(), "src/{layer}/ has files");
        for path in files {
            let text = code(&path);
            let mut uses = after(&text, "crate::");
            if after(&text, "ash::").iter().next().is_some() || text.contains("use ash;") {
                uses.insert("ash".into());
            }
            for f in forbidden {
                assert!(
                    !uses.contains(*f),
                    "{} ({layer}/) imports {f}",
                    path.display()
                );
            }
            checked += 1;
        }
    }
    assert!(checked > 50, "{checked} files checked");
    // The reader sees an import where there is one.
    assert!(after("use crate::render::view::View;", "crate::").contains("render"));
    assert!(after("x = vellum::crate::gpu", "crate::").is_empty());
}
