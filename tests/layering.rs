//! The architecture of ARCHITECTURE.md, checked where Cargo does not check it by itself:
//! - the crate graph: each crate of the workspace depends on exactly the crates of ours it is
//!   meant to (Cargo then refuses any import that goes up a layer), no Vulkan crate sits beneath
//!   `vellum-volume`, only the viewer pulls the window stack (winit, egui), only the tools pull MPI, and the
//!   Python extension depends on the library crates alone;
//! - no import cycle between the files of any crate (or of the binary).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The triple of the machine the tests run on, from `rustc -vV`.
fn host_triple() -> String {
    let out = std::process::Command::new("rustc")
        .arg("-vV")
        .output()
        .expect("rustc -vV runs");
    let text = String::from_utf8_lossy(&out.stdout);
    text.lines()
        .find_map(|l| l.strip_prefix("host: "))
        .expect("rustc -vV names the host")
        .trim()
        .to_string()
}

/// `cargo metadata` of the workspace, resolved (every feature, so that optional crates count)
/// for this machine's platform: offline, a clean machine's registry holds only the crates its
/// builds fetched, not those of other platforms (winit's Android crates, say).
fn metadata() -> serde_json::Value {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = std::process::Command::new(cargo)
        .args([
            "metadata",
            "--format-version",
            "1",
            "--all-features",
            "--offline",
            "--filter-platform",
            &host_triple(),
        ])
        .current_dir(root())
        .output()
        .expect("cargo metadata runs");
    assert!(
        out.status.success(),
        "cargo metadata: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("cargo metadata's JSON")
}

/// The resolved graph: package name → the names of its normal (not dev or build) dependencies.
fn graph(meta: &serde_json::Value) -> BTreeMap<String, BTreeSet<String>> {
    let name_of: BTreeMap<&str, &str> = meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| (p["id"].as_str().unwrap(), p["name"].as_str().unwrap()))
        .collect();
    let mut graph = BTreeMap::new();
    for node in meta["resolve"]["nodes"].as_array().unwrap() {
        let deps = node["deps"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|d| {
                d["dep_kinds"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .any(|k| k["kind"].is_null())
            })
            .map(|d| name_of[d["pkg"].as_str().unwrap()].to_string())
            .collect();
        graph.insert(name_of[node["id"].as_str().unwrap()].to_string(), deps);
    }
    graph
}

/// Every package `name` depends on, directly or not.
fn beneath(graph: &BTreeMap<String, BTreeSet<String>>, name: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut pending = vec![name.to_string()];
    while let Some(n) = pending.pop() {
        for d in graph.get(&n).into_iter().flatten() {
            if seen.insert(d.clone()) {
                pending.push(d.clone());
            }
        }
    }
    seen
}

/// Each crate of ours and the crates of ours it depends on: the intended graph.
const OURS: [(&str, &[&str]); 8] = [
    ("vellum-error", &[]),
    ("vellum-gpu", &["vellum-error"]),
    ("vellum-volume", &["vellum-error"]),
    (
        "vellum-render",
        &["vellum-error", "vellum-gpu", "vellum-volume"],
    ),
    (
        "vellum-viewer",
        &[
            "vellum-error",
            "vellum-gpu",
            "vellum-volume",
            "vellum-render",
        ],
    ),
    (
        "vellum-tools",
        &[
            "vellum-error",
            "vellum-gpu",
            "vellum-volume",
            "vellum-render",
        ],
    ),
    (
        "vellum",
        &[
            "vellum-error",
            "vellum-gpu",
            "vellum-volume",
            "vellum-render",
            "vellum-viewer",
            "vellum-tools",
        ],
    ),
    // The Python extension: the library crates only, not the binary's tools, and not the
    // windowed viewer (winit, egui), since a Python user has no window to open.
    (
        "vellum-python",
        &[
            "vellum-error",
            "vellum-gpu",
            "vellum-volume",
            "vellum-render",
        ],
    ),
];

#[test]
fn the_crate_graph_is_the_intended_one() {
    let graph = graph(&metadata());
    let ours = |deps: &BTreeSet<String>| -> BTreeSet<String> {
        deps.iter()
            .filter(|d| d.starts_with("vellum"))
            .cloned()
            .collect()
    };
    let members: BTreeSet<String> = graph
        .keys()
        .filter(|k| k.starts_with("vellum"))
        .cloned()
        .collect();
    let intended: BTreeSet<String> = OURS.iter().map(|(n, _)| n.to_string()).collect();
    assert_eq!(members, intended, "the workspace's crates");
    for (name, deps) in OURS {
        let want: BTreeSet<String> = deps.iter().map(|d| d.to_string()).collect();
        assert_eq!(ours(&graph[name]), want, "{name}'s dependencies of ours");
    }
    // The window stack (vellum-gpu's swapchain needs only ash-window and raw-window-handle).
    let window = ["winit", "egui", "egui-winit", "egui-ash-renderer"];
    for (name, _) in OURS {
        let all = beneath(&graph, name);
        let vulkan = all.contains("ash") || all.contains("gpu-allocator");
        if matches!(name, "vellum-error" | "vellum-volume") {
            assert!(!vulkan, "{name} depends on no Vulkan crate");
        }
        if !matches!(name, "vellum-viewer" | "vellum") {
            for w in window {
                assert!(!all.contains(w), "{name} depends on {w}");
            }
        }
        if !matches!(name, "vellum-tools" | "vellum") {
            assert!(!all.contains("mpi"), "{name} depends on mpi");
        }
    }
    // Vulkan's API crate is named only by the GPU crate, and by the viewer's shell where it
    // hands egui-ash-renderer what that takes; the passes and renderers speak vellum-gpu's types.
    for (name, _) in OURS {
        let direct = graph[name].contains("ash");
        assert_eq!(
            direct,
            matches!(name, "vellum-gpu" | "vellum-viewer"),
            "{name} names ash directly: {direct}"
        );
    }
    // The checker sees a dependency where there is one.
    assert!(beneath(&graph, "vellum-render").contains("ash"));
    assert!(beneath(&graph, "vellum-viewer").contains("winit"));
}

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
    files.sort();
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

/// The module path of a file under a crate's `src` (`passes/importance.rs` → `passes::importance`;
/// `lib.rs`, `main.rs` and `mod.rs` name their folder's module).
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap();
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| {
            c.as_os_str()
                .to_string_lossy()
                .trim_end_matches(".rs")
                .to_string()
        })
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("lib" | "main" | "mod")
    ) {
        parts.pop();
    }
    parts
}

/// The paths a file names after `crate::` and `super::`, as module paths from the crate's root.
fn named_paths(text: &str, module: &[String]) -> Vec<Vec<String>> {
    let mut paths = Vec::new();
    let parent = module[..module.len().saturating_sub(1)].to_vec();
    for (prefix, base) in [("crate::", Vec::new()), ("super::", parent)] {
        for (i, _) in text.match_indices(prefix) {
            let before = text[..i].chars().next_back();
            if before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':' || c == '$') {
                continue;
            }
            let tail: String = text[i + prefix.len()..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                .collect();
            let mut path = base.clone();
            path.extend(tail.split("::").filter(|s| !s.is_empty()).map(String::from));
            paths.push(path);
        }
    }
    paths
}

/// The file-level import graph of the crate whose root folder is `src`: file → files it names,
/// through `crate::` and `super::` paths resolved to the deepest module that has a file. Facade
/// files (lib.rs, main.rs, mod.rs), which declare and re-export their children, are left out.
fn file_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let files = rust_files(src);
    let modules: BTreeMap<Vec<String>, String> = files
        .iter()
        .map(|f| {
            (
                module_of(src, f),
                f.strip_prefix(src).unwrap().display().to_string(),
            )
        })
        .collect();
    let facade = |f: &str| f.ends_with("lib.rs") || f.ends_with("main.rs") || f.ends_with("mod.rs");
    let mut graph = BTreeMap::new();
    for file in &files {
        let name = file.strip_prefix(src).unwrap().display().to_string();
        if facade(&name) {
            continue;
        }
        let module = module_of(src, file);
        let mut deps = BTreeSet::new();
        for mut path in named_paths(&code(file), &module) {
            while !path.is_empty() && !modules.contains_key(&path) {
                path.pop();
            }
            if let Some(target) = modules.get(&path) {
                if !facade(target) && *target != name {
                    deps.insert(target.clone());
                }
            }
        }
        graph.insert(name, deps);
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
fn no_crate_has_an_import_cycle_between_its_files() {
    let mut folders: Vec<PathBuf> = std::fs::read_dir(root().join("crates"))
        .unwrap()
        .map(|e| e.unwrap().path().join("src"))
        .collect();
    folders.sort();
    folders.push(root().join("src/bin/vellum"));
    folders.push(root().join("python/src"));
    let mut files = 0;
    for src in &folders {
        let graph = file_graph(src);
        files += graph.len();
        assert_eq!(cycle(&graph), None, "an import cycle in {}", src.display());
    }
    assert!(files > 100, "{files} files read");
    // The reader sees imports, and the checker finds a cycle where there is one.
    let render = file_graph(&root().join("crates/vellum-render/src"));
    assert!(render["render/frame.rs"].contains("render/raycast.rs"));
    let mut looped = render.clone();
    looped
        .get_mut("render/view.rs")
        .unwrap()
        .insert("render/frame.rs".into());
    assert!(cycle(&looped).is_some());
}

/// The layers inside `vellum-render`, which share a crate: each module and those it must never
/// import (ARCHITECTURE.md). `imaging` is 2D CPU work and imports no Vulkan.
const INSIDE_RENDER: [(&str, &[&str]); 3] = [
    (
        "imaging",
        &["classify", "passes", "render", "vellum_gpu", "ash"],
    ),
    ("classify", &["passes", "render"]),
    ("passes", &["render"]),
];

#[test]
fn inside_the_render_crate_no_module_imports_one_above_it() {
    let src = root().join("crates/vellum-render/src");
    let mut checked = 0;
    for (module, forbidden) in INSIDE_RENDER {
        for file in rust_files(&src.join(module)) {
            let text = code(&file);
            for f in forbidden {
                let named = match *f {
                    "vellum_gpu" | "ash" => text.contains(&format!("{f}::")),
                    _ => text.contains(&format!("crate::{f}::")),
                };
                assert!(!named, "{} ({module}/) imports {f}", file.display());
            }
            checked += 1;
        }
    }
    assert!(checked > 20, "{checked} files checked");
}

#[test]
fn no_file_of_the_viewer_is_over_600_lines() {
    let files = rust_files(&root().join("crates/vellum-viewer/src"));
    assert!(files.len() >= 8, "{} files read", files.len());
    for file in files {
        let lines = std::fs::read_to_string(&file).unwrap().lines().count();
        assert!(lines <= 600, "{} has {lines} lines", file.display());
    }
}
