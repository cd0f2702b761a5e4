//! What `make bench-device` sends to a lent GPU and how its results come back (issue 30), checked
//! without a GPU:
//! - the cut-down VTK keeps every wrapper module the VTK peer imports;
//! - `tables.py` turns a results folder into BENCHMARKS.md's GPU section, the VTK goal judged from
//!   the wall-clock ratio, and leaves the text outside its markers alone, and the sections
//!   written by hand between them too.

use std::path::{Path, PathBuf};
use std::process::Command;

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// The `vtkmodules.X` names a Python file imports, by either form of import.
fn vtk_imports(source: &str) -> Vec<String> {
    let mut names: Vec<String> = source
        .lines()
        .filter_map(|l| {
            let l = l.trim();
            let rest = l
                .strip_prefix("import vtkmodules.")
                .or_else(|| l.strip_prefix("from vtkmodules."))?;
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric())
                .collect();
            (name.starts_with("vtk")).then_some(name)
        })
        .collect();
    names.sort();
    names.dedup();
    names
}

#[test]
fn the_cut_down_vtk_keeps_what_the_peer_imports() {
    let peer = std::fs::read_to_string(repo("benches/vtk_peer.py")).unwrap();
    let slim = std::fs::read_to_string(repo("benches/device/slim_vtk.py")).unwrap();
    let imports = vtk_imports(&peer);
    assert!(
        imports.len() >= 6,
        "vtk_peer.py should import VTK module by module, found {imports:?}"
    );
    assert!(
        !peer.lines().any(|l| l.trim() == "import vtk"),
        "vtk_peer.py imports the whole of VTK, which the cut-down package lacks"
    );
    let list = slim
        .split("PEER = [")
        .nth(1)
        .and_then(|s| s.split(']').next())
        .expect("slim_vtk.py has a PEER list");
    let kept: Vec<String> = list
        .split(',')
        .map(|s| s.trim().trim_matches('"').to_string())
        .filter(|s| !s.is_empty())
        .collect();
    let missing: Vec<&String> = imports.iter().filter(|m| !kept.contains(m)).collect();
    assert!(
        missing.is_empty(),
        "slim_vtk.py's PEER lacks {missing:?}, which vtk_peer.py imports"
    );
}

fn peer_json(vtk_ms: [f64; 2], wall_ms: [f64; 2]) -> String {
    let rows: Vec<String> = [256, 1024]
        .iter()
        .enumerate()
        .map(|(i, size)| {
            format!(
                r#"{{"size": {size}, "vtk_ms": {v}, "slicer_ms": 9.0, "raycast_ms": 0.8,
                "raycast_wall_ms": {w}, "vtk_over_slicer": 1.0, "vtk_over_raycast": 1.0,
                "vtk_over_raycast_wall": {r}}}"#,
                v = vtk_ms[i],
                w = wall_ms[i],
                r = vtk_ms[i] / wall_ms[i]
            )
        })
        .collect();
    format!(
        r#"{{"device": "NVIDIA H100 80GB HBM3", "rows": [], "orbit": [],
        "peer": {{"vtk_renderer": "NVIDIA H100 80GB HBM3/PCIe/SSE2", "frames": 18,
        "images": "/tmp/x", "rows": [{}]}}}}"#,
        rows.join(",")
    )
}

/// Runs tables.py on a folder holding these results (`vtk` → vtk.json, ...) and returns the
/// Markdown it wrote.
fn tables(results_json: &[(&str, &str)]) -> String {
    tables_over(results_json, "# Benchmarks\n\nkept before\n")
}

/// [`tables`] over a BENCHMARKS.md that holds `markdown` first.
fn tables_over(results_json: &[(&str, &str)], markdown: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let results = dir.path().join("results");
    std::fs::create_dir(&results).unwrap();
    std::fs::write(results.join("device.txt"), "date: 2026-11-26T00:00Z\n").unwrap();
    for (name, json) in results_json {
        std::fs::write(results.join(format!("{name}.json")), json).unwrap();
    }
    let md = dir.path().join("BENCHMARKS.md");
    std::fs::write(&md, markdown).unwrap();
    // Twice: the second run replaces the section the first wrote.
    for _ in 0..2 {
        let out = Command::new("python3")
            .arg(repo("benches/device/tables.py"))
            .arg(&results)
            .arg(&md)
            .output()
            .expect("python3 runs");
        assert!(
            out.status.success(),
            "tables.py failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    std::fs::read_to_string(&md).unwrap()
}

#[test]
fn tables_judge_the_vtk_goal_by_wall_time() {
    // 2 ms against VTK's 10 at 256² (0.2×) and 3 against 20 at 1024² (0.15×): met.
    let md = tables(&[("vtk", &peer_json([10.0, 20.0], [2.0, 3.0]))]);
    assert!(md.starts_with("# Benchmarks\n\nkept before\n"), "{md}");
    let row = md
        .lines()
        .find(|l| l.starts_with("| VTK's GPU ray caster"))
        .expect("a VTK goal row");
    assert!(
        row.contains("256²: 0.200×") && row.contains("1024²: 0.150×"),
        "{row}"
    );
    assert!(row.ends_with("| **met** |"), "{row}");
    assert!(md.contains("### Against VTK"), "{md}");
    // One size above 0.25× fails the goal.
    let md = tables(&[("vtk", &peer_json([10.0, 20.0], [3.0, 3.0]))]);
    let row = md
        .lines()
        .find(|l| l.starts_with("| VTK's GPU ray caster"))
        .unwrap();
    assert!(row.ends_with("| not met |"), "{row}");
    // A size VTK gave no time for (NaN, written as null) is left out, not a crash.
    let partial =
        peer_json([10.0, 20.0], [2.0, 3.0]).replacen("\"vtk_ms\": 20", "\"vtk_ms\": null", 1);
    let md_partial = tables(&[("vtk", &partial)]);
    let row = md_partial
        .lines()
        .find(|l| l.starts_with("| VTK's GPU ray caster"))
        .unwrap();
    assert!(
        row.contains("256²: 0.200×") && !row.contains("1024²"),
        "{row}"
    );
    // Written twice over the same file: one section, replaced in place.
    assert_eq!(md.matches("<!-- bench-device:begin -->").count(), 1, "{md}");
}

#[test]
fn tables_judge_the_bricked_goal_by_the_fastest_lookup() {
    let bricked = r#"{"rows": [
        {"case": "core_skip", "ms": [1.0, 1.0, 1.0]},
        {"case": "bricked_lookup", "ms": [1.9, 1.9, 1.9]},
        {"case": "bricked_reuse", "ms": [1.5, 1.4, 1.5]},
        {"case": "bricked_span", "ms": [1.1, 1.15, 1.2]},
        {"case": "bricked_failed", "ms": []}]}"#;
    let md = tables(&[("bricked", bricked)]);
    let row = md
        .lines()
        .find(|l| l.starts_with("| bricked ray caster"))
        .expect("a bricked goal row");
    assert!(
        row.contains("1.150 ms (bricked_span) against 1.000 ms: 1.15×"),
        "{row}"
    );
    assert!(row.ends_with("| **met** |"), "{row}");
}

/// Issue 43's skipping goal: met only where no pair of renders is slower with skipping.
#[test]
fn tables_judge_skipping_by_its_worst_pair() {
    let row_of = |bricked: &str| {
        let md = tables(&[("bricked", bricked)]);
        md.lines()
            .find(|l| l.starts_with("| empty-space skipping"))
            .expect("a skipping goal row")
            .to_string()
    };
    let faster = r#"{"rows": [
        {"case": "head_skip", "ms": [0.5, 0.5, 0.5]}, {"case": "head_noskip", "ms": [0.7, 0.7, 0.7]},
        {"case": "engine1p_skip", "ms": [0.6, 0.6, 0.6]}, {"case": "engine1p_noskip", "ms": [0.6, 0.6, 0.6]}]}"#;
    let row = row_of(faster);
    assert!(row.contains("CT head two levels 0.71×"), "{row}");
    assert!(row.ends_with("| **met** |"), "{row}");
    let slower = faster.replace(
        "[0.6, 0.6, 0.6]}, {\"case\": \"engine1p_noskip\"",
        "[0.62, 0.62, 0.62]}, {\"case\": \"engine1p_noskip\"",
    );
    let row = row_of(&slower);
    assert!(row.contains("engine one pass 1.03×"), "{row}");
    assert!(row.ends_with("| not met |"), "{row}");
}

#[test]
fn a_rewrite_keeps_the_sections_around_and_between_the_markers() {
    let before = "# Benchmarks\n\n## Out of core\n\nstores\n\n<!-- bench-device:begin -->\n\
        ## Many ranks on MPI\n\nranks\n\n## The first five minutes\n\nfirst\n\n\
        ## On a GPU: every bench through `make bench-device` (issue 30)\n\nold figures\n\
        <!-- bench-device:end -->\n\n## After the GPU\n\nafter\n";
    let md = tables_over(&[], before);
    for kept in [
        "## Out of core\n\nstores",
        "## Many ranks on MPI\n\nranks",
        "## The first five minutes\n\nfirst",
        "## After the GPU\n\nafter",
    ] {
        assert!(md.contains(kept), "{kept:?} is gone:\n{md}");
    }
    assert!(
        !md.contains("old figures"),
        "the old GPU section stays:\n{md}"
    );
    assert_eq!(md.matches("## On a GPU").count(), 1, "{md}");
    // The kept sections now sit before the markers, which hold the generated section alone.
    let inside = md.split("<!-- bench-device:begin -->").nth(1).unwrap();
    assert!(inside.trim_start().starts_with("## On a GPU"), "{md}");
}
