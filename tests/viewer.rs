//! The windowed viewer driven as a user would: a real window on Xvfb, real X events from xdotool
//! (drag, keys, clicks, resize), screenshots compared with each other and with `vellum render
//! --scene`. Validation and synchronization validation are on, and any message fails the test.
//! Each test runs its own X server and one viewer process.
//!
//! Needs Xvfb and xdotool (the README's set-up installs them); without them a test says so and
//! passes, except under CI=true, where it fails.

#![cfg(feature = "viewer")]

#[path = "common/http_server.rs"]
mod http_server;

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const VELLUM: &str = env!("CARGO_BIN_EXE_vellum");

/// An X server on a display of its own, stopped on drop.
struct Xvfb {
    child: Child,
    display: String,
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn have(tool: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {tool}")])
        .output()
        .is_ok_and(|o| o.status.success())
}

/// Starts Xvfb, or returns None (after saying why) where it or xdotool is missing outside CI.
fn xvfb() -> Option<(Xvfb, std::sync::MutexGuard<'static, ()>)> {
    // One viewer at a time: two would share the two cores and each would wait on the other.
    static ONE: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let guard = ONE.lock().unwrap_or_else(|p| p.into_inner());
    if !have("Xvfb") || !have("xdotool") {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "Xvfb and xdotool are needed for the viewer tests; `make deps` installs them"
        );
        eprintln!("skipped: Xvfb or xdotool is missing (make deps installs them)");
        return None;
    }
    // -displayfd: the server picks a free display and writes its number when it is ready.
    let mut child = Command::new("Xvfb")
        .args([
            "-displayfd",
            "1",
            "-screen",
            "0",
            "1280x1024x24",
            "-nolisten",
            "tcp",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("starting Xvfb");
    let mut line = String::new();
    BufReader::new(child.stdout.take().expect("piped"))
        .read_line(&mut line)
        .expect("reading Xvfb's display number");
    let n: u32 = line
        .trim()
        .parse()
        .expect("Xvfb printed its display number");
    Some((
        Xvfb {
            child,
            display: format!(":{n}"),
        },
        guard,
    ))
}

fn xdotool(x: &Xvfb, args: &[&str]) -> String {
    let out = Command::new("xdotool")
        .args(args)
        .env("DISPLAY", &x.display)
        .output()
        .expect("running xdotool");
    assert!(
        out.status.success(),
        "xdotool {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A running `vellum view` and its window.
struct Viewer {
    child: Child,
    window: String,
    lines: mpsc::Receiver<String>,
    stderr: std::thread::JoinHandle<String>,
    /// The last "layout ..." line seen.
    layout: std::cell::RefCell<String>,
    /// Every "message: ..." line seen.
    messages: std::cell::RefCell<Vec<String>>,
}

fn start(x: &Xvfb, dir: &Path, args: &[&str]) -> Viewer {
    let mut child = Command::new(VELLUM)
        .arg("view")
        .args(args)
        .arg("--screenshot-dir")
        .arg(dir)
        .env("DISPLAY", &x.display)
        .env("VELLUM_VALIDATION", "1")
        .env("VELLUM_SYNC_VALIDATION", "1")
        .env("VELLUM_VIEW_LAYOUT", "1")
        .env("VELLUM_VIEW_OCCLUSION_DELAY_MS", "3000")
        .env(
            "XDG_RUNTIME_DIR",
            std::env::var("XDG_RUNTIME_DIR").unwrap_or_else(|_| dir.display().to_string()),
        )
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starting vellum view");
    let stdout: ChildStdout = child.stdout.take().expect("piped");
    let (tx, lines) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(|l| l.ok()) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut err = child.stderr.take().expect("piped");
    let stderr = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = err.read_to_string(&mut s);
        s
    });
    let window = xdotool(
        x,
        &["search", "--sync", "--onlyvisible", "--class", "vellum"],
    )
    .lines()
    .next()
    .expect("the viewer's window")
    .to_string();
    // Keys go to the focused window (there is no window manager to give it focus).
    xdotool(x, &["windowfocus", "--sync", &window]);
    Viewer {
        child,
        window,
        lines,
        stderr,
        layout: Default::default(),
        messages: Default::default(),
    }
}

impl Viewer {
    /// Waits for a line of the viewer's stdout that starts with `prefix`.
    fn expect(&self, prefix: &str) -> String {
        let deadline = Instant::now() + Duration::from_secs(120);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.lines.recv_timeout(left) {
                Ok(l) => {
                    if l.starts_with("layout ") {
                        *self.layout.borrow_mut() = l.clone();
                    }
                    if l.starts_with("message: ") {
                        self.messages.borrow_mut().push(l.clone());
                    }
                    if l.starts_with(prefix) {
                        return l;
                    }
                }
                Err(e) => panic!("the viewer never printed {prefix:?}: {e}"),
            }
        }
    }

    /// The latest layout the viewer printed (after draining what it has printed so far).
    fn layout(&self) -> ([i64; 4], Option<[i64; 4]>) {
        while let Ok(l) = self.lines.try_recv() {
            if l.starts_with("layout ") {
                *self.layout.borrow_mut() = l;
            }
        }
        parse_layout(&self.layout.borrow())
    }

    /// Presses S and returns the screenshot's path once it is written.
    fn screenshot(&self, x: &Xvfb) -> PathBuf {
        xdotool(x, &["key", "s"]);
        let l = self.expect("screenshot: ");
        PathBuf::from(l.trim_start_matches("screenshot: "))
    }

    /// Presses Escape and checks the exit: status 0, no validation message, no panic.
    fn close(mut self, x: &Xvfb) {
        xdotool(x, &["key", "Escape"]);
        let deadline = Instant::now() + Duration::from_secs(60);
        let status = loop {
            if let Some(s) = self.child.try_wait().expect("waiting for the viewer") {
                break s;
            }
            if Instant::now() > deadline {
                let _ = self.child.kill();
                panic!("the viewer did not close on Escape");
            }
            std::thread::sleep(Duration::from_millis(100));
        };
        let stderr = self.stderr.join().unwrap_or_default();
        assert!(
            status.success(),
            "the viewer exited with {status}: {stderr}"
        );
        assert!(
            !stderr.contains("validation layer reported") && !stderr.contains("panicked"),
            "{stderr}"
        );
    }
}

/// Time for the viewer to draw a frame between two X events on a panel: egui tells a drag from a
/// click across frames, and a frame of the larger test views takes up to a second on lavapipe.
const PAUSE: Duration = Duration::from_millis(1200);

/// A left click at `at` (window pixels) in `window`. egui acts on a click over a widget it
/// already knows the pointer is over: move, let a frame pass, then click.
fn click(x: &Xvfb, window: &str, at: [i64; 2]) {
    let (cx, cy) = (at[0].to_string(), at[1].to_string());
    xdotool(x, &["mousemove", "--window", window, &cx, &cy]);
    std::thread::sleep(Duration::from_millis(300));
    xdotool(x, &["click", "1"]);
}

/// The centre of a layout rectangle.
fn centre(r: [i64; 4]) -> [i64; 2] {
    [r[0] + r[2] / 2, r[1] + r[3] / 2]
}

/// A left-button drag in `window` from `from`, by `step` pixels `steps` times, pausing between
/// events.
fn drag(x: &Xvfb, window: &str, from: [i64; 2], step: [i64; 2], steps: usize, pause: Duration) {
    let [fx, fy] = from.map(|v| v.to_string());
    xdotool(x, &["mousemove", "--window", window, &fx, &fy]);
    std::thread::sleep(pause);
    xdotool(x, &["mousedown", "1"]);
    std::thread::sleep(pause);
    for _ in 0..steps {
        let [dx, dy] = step.map(|v| v.to_string());
        xdotool(x, &["mousemove_relative", "--", &dx, &dy]);
        std::thread::sleep(pause);
    }
    xdotool(x, &["mouseup", "1"]);
    std::thread::sleep(pause);
}

fn rgb(path: &Path) -> image::RgbImage {
    image::open(path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgb8()
}

/// Mean and largest absolute difference per channel, in 8-bit steps.
fn difference(a: &image::RgbImage, b: &image::RgbImage) -> (f64, u8) {
    assert_eq!(a.dimensions(), b.dimensions());
    let mut sum = 0u64;
    let mut max = 0u8;
    for (p, q) in a.as_raw().iter().zip(b.as_raw()) {
        let d = p.abs_diff(*q);
        sum += d as u64;
        max = max.max(d);
    }
    (sum as f64 / a.as_raw().len() as f64, max)
}

/// Renders `scene` with `vellum render` (at `size` when given) and checks it equals `shot` within
/// the rounding of one 8-bit step.
fn assert_render_matches(scene: &Path, size: Option<&str>, shot: &image::RgbImage, dir: &Path) {
    let out = dir.join("render.png");
    let mut cmd = Command::new(VELLUM);
    cmd.args(["render", "--scene"])
        .arg(scene)
        .arg("--out")
        .arg(&out);
    if let Some(s) = size {
        cmd.args(["--size", s]);
    }
    let status = cmd
        .env("VELLUM_VALIDATION", "1")
        .status()
        .expect("running vellum render");
    assert!(status.success());
    let (mean, max) = difference(shot, &rgb(&out));
    assert!(
        mean <= 0.5 && max <= 2,
        "viewer and `render --scene` differ: mean {mean:.3}, max {max}"
    );
}

/// Opens `scene` in a window of `size`, takes a first screenshot, and returns it with the layout
/// drawn after it (the screenshot changes the panel's message line).
fn open_scene(x: &Xvfb, dir: &Path, scene: &Path, size: &str) -> (Viewer, image::RgbImage, String) {
    let v = start(
        x,
        dir,
        &["--scene", scene.to_str().expect("utf-8"), "--size", size],
    );
    v.expect("layout view");
    let first = rgb(&v.screenshot(x));
    std::thread::sleep(Duration::from_millis(1000));
    v.layout();
    let line = v.layout.borrow().clone();
    (v, first, line)
}

/// "layout view X Y W H [NAME X Y W H]..." → (view, the transfer-function editor).
fn parse_layout(line: &str) -> ([i64; 4], Option<[i64; 4]>) {
    (
        mark(line, "view").expect("the view's rectangle"),
        mark(line, "tf-editor"),
    )
}

/// The rectangle named `name` in a layout line.
fn mark(line: &str, name: &str) -> Option<[i64; 4]> {
    let v: Vec<&str> = line.split_whitespace().collect();
    let i = v.iter().position(|t| *t == name)?;
    let num = |k: usize| v[i + k].parse::<i64>().expect("a layout number");
    Some([num(1), num(2), num(3), num(4)])
}

/// Drag to orbit, edit the transfer function with a click, save the scene (Ctrl+S), resize; each
/// step changes the screenshot as it should, and the saved scene renders from the command line
/// to the viewer's screenshot.
#[test]
fn orbit_edit_save_and_resize_through_x_events() {
    let Some((x, _one)) = xvfb() else { return };
    let dir = tempfile::tempdir().expect("a temporary folder");
    // The two-point grey ramp, whose last point sets the opacity of every value (the default
    // `auto` window has 17 points, and its last one only the densest few).
    let v = start(
        &x,
        dir.path(),
        &[
            "phantom:shepp-logan:48",
            "--size",
            "720x480",
            "--tf",
            "grey",
        ],
    );
    v.expect("layout view");
    let (view, _) = v.layout();
    let before = rgb(&v.screenshot(&x));
    assert_eq!(
        before.dimensions(),
        (view[2] as u32, view[3] as u32),
        "a screenshot is the volume view's size"
    );

    // A left drag across the volume view orbits the camera.
    let (cx, cy) = (view[0] + view[2] / 2, view[1] + view[3] / 2);
    let w = &v.window;
    drag(&x, w, [cx, cy], [15, 4], 4, Duration::from_millis(100));
    let orbited = rgb(&v.screenshot(&x));
    let (mean, _) = difference(&before, &orbited);
    assert!(
        mean > 1.0,
        "the drag did not change the image (mean difference {mean:.3})"
    );

    // Saving the scene (Ctrl+S) writes the camera the drag made.
    xdotool(&x, &["key", "ctrl+s"]);
    let scene = dir.path().join("vellum.scene.json");
    let deadline = Instant::now() + Duration::from_secs(60);
    while !scene.exists() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(scene.exists(), "Ctrl+S wrote no scene");

    // Dragging the transfer function's last control point (the densest values, opacity 1) to the
    // bottom of the editor makes the skull transparent.
    std::thread::sleep(Duration::from_millis(1000));
    let (_, tf) = v.layout();
    let tf = tf.expect("the transfer-function editor is on screen");
    let (px, py) = (tf[0] + tf[2] - 2, tf[1] + 2);
    drag(&x, w, [px, py], [0, tf[3] / 3], 4, PAUSE);
    let edited = rgb(&v.screenshot(&x));
    let (mean, _) = difference(&orbited, &edited);
    assert!(
        mean > 1.0,
        "the transfer-function edit did not change the image ({mean:.3})"
    );

    // Resizing the window resizes the view; validation stays silent (checked at close).
    xdotool(&x, &["windowsize", w, "800", "560"]);
    let (view2, _) = parse_layout(&v.expect("layout view"));
    let resized = rgb(&v.screenshot(&x));
    assert_eq!(resized.dimensions(), (view2[2] as u32, view2[3] as u32));
    assert_ne!(view2, view);
    v.close(&x);

    // The saved scene, rendered by the CLI, equals the screenshot taken when it was saved.
    assert_render_matches(&scene, None, &orbited, dir.path());
}

/// A scene file opened in the viewer, with the panel hidden (H), shows what `vellum render
/// --scene` renders at the window's size.
#[test]
fn a_loaded_scene_matches_render() {
    let Some((x, _one)) = xvfb() else { return };
    let dir = tempfile::tempdir().expect("a temporary folder");
    let scene = dir.path().join("scene.json");
    std::fs::write(
        &scene,
        r#"{"version": 1, "input": {"path": "phantom:shepp-logan:40"},
            "classification": {"transfer": "ct-skin-bone"}, "focus": {"iso": 0.9},
            "camera": {"azimuth": 60, "elevation": 25}, "background": [0.1, 0.2, 0.3],
            "style": {"style": "sobel"}, "size": [64, 64]}"#,
    )
    .expect("writing the scene");
    let v = start(
        &x,
        dir.path(),
        &[
            "--scene",
            scene.to_str().expect("utf-8"),
            "--size",
            "400x300",
        ],
    );
    v.expect("layout view");
    xdotool(&x, &["key", "h"]);
    let (view, _) = parse_layout(&v.expect("layout view 0 0"));
    assert_eq!(
        view,
        [0, 0, 400, 300],
        "without the panel the view is the window"
    );
    let shot = rgb(&v.screenshot(&x));
    v.close(&x);
    assert_render_matches(&scene, Some("400x300"), &shot, dir.path());
}

/// The occlusion editor: a rectangle dragged on the spectrum tags a region that changes the
/// image, and the scene saved with it (its OTF beside it) renders from the command line to the
/// viewer's screenshot. The feature map: unticking a feature hides it.
#[test]
fn occlusion_and_feature_editors_change_the_image() {
    let Some((x, _one)) = xvfb() else { return };
    let dir = tempfile::tempdir().expect("a temporary folder");
    let examples = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");

    let scene = examples.join("occlusion_nested.json");
    let (v, before, line) = open_scene(&x, dir.path(), &scene, "760x900");
    let sp = mark(&line, "spectrum").expect("the spectrum is on screen");
    let w = &v.window;
    let at = |fx: i64, fy: i64| [sp[0] + sp[2] * fx / 100, sp[1] + sp[3] * fy / 100];
    let [x0, y0] = at(5, 5);
    drag(&x, w, [x0, y0], [sp[2] / 7, sp[3] / 7], 6, PAUSE);
    let tagged = rgb(&v.screenshot(&x));
    let (mean, _) = difference(&before, &tagged);
    assert!(
        mean > 1.0,
        "tagging a region did not change the image ({mean:.3})"
    );
    xdotool(&x, &["key", "ctrl+s"]);
    let saved = dir.path().join("vellum.scene.json");
    let otf = dir.path().join("vellum.scene.otf.json");
    let deadline = Instant::now() + Duration::from_secs(60);
    while !(saved.exists() && otf.exists()) && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(otf.exists(), "Ctrl+S wrote no OTF beside the scene");
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&otf).expect("reading the OTF"))
            .expect("the OTF is JSON");
    let regions = written["regions"].as_array().map_or(0, Vec::len);
    assert_eq!(regions, 3, "the example's two regions and the tagged one");

    // Recomputing the occlusion runs on a worker (held back 3 s by the test hook): the window
    // keeps drawing meanwhile, and the same radius gives the same picture afterwards.
    v.layout();
    let line = v.layout.borrow().clone();
    let r = mark(&line, "recompute-occlusion").expect("the recompute button is on screen");
    click(&x, w, centre(r));
    xdotool(&x, &["key", "s"]);
    let during = loop {
        let l = v.expect("");
        assert!(
            !l.starts_with("message: occlusion at R"),
            "the occlusion finished before a frame was drawn while it ran: {l}"
        );
        if let Some(p) = l.strip_prefix("screenshot: ") {
            break rgb(Path::new(p));
        }
    };
    let done = loop {
        let l = v.expect("message: ");
        if l.contains("occlusion") {
            break l;
        }
    };
    assert!(
        done.contains("recomputed") && done.contains("second device"),
        "{done}"
    );
    let after = rgb(&v.screenshot(&x));
    let (mean, max) = difference(&tagged, &during);
    assert!(
        mean < 0.5 && max <= 2,
        "the frame during the recomputation changed ({mean:.3}, {max})"
    );
    let (mean, max) = difference(&tagged, &after);
    assert!(
        mean < 0.5 && max <= 8,
        "the recomputed occlusion changed the image ({mean:.3}, {max})"
    );
    v.close(&x);
    assert_render_matches(&saved, None, &tagged, dir.path());

    let scene = examples.join("features_nested.json");
    let (v, before, line) = open_scene(&x, dir.path(), &scene, "1200x800");
    let b = mark(&line, "feature:sphere").expect("the feature's box is on screen");
    click(&x, &v.window, centre(b));
    std::thread::sleep(Duration::from_millis(300));
    let hidden = rgb(&v.screenshot(&x));
    // The feature is orange (its colour in the map); the context is grey.
    let orange = |im: &image::RgbImage| {
        im.pixels()
            .filter(|p| p[0] as i32 > p[2] as i32 + 40 && p[0] > 60)
            .count()
    };
    let (shown, left) = (orange(&before), orange(&hidden));
    assert!(
        shown > 200,
        "the feature is not on screen ({shown} orange pixels)"
    );
    assert_eq!(
        left, 0,
        "the hidden feature still shows ({left} orange pixels)"
    );
    v.close(&x);
}

/// The decoupled model's Gaussian occlusion curve has handles on the spectrum: dragging its mean
/// handle down moves the mean, changes the image, and the saved OTF holds the new mean.
#[test]
fn an_occlusion_curve_is_dragged_by_its_handle() {
    let Some((x, _one)) = xvfb() else { return };
    let dir = tempfile::tempdir().expect("a temporary folder");
    std::fs::write(
        dir.path().join("curve.otf.json"),
        r#"{"radius": 6, "transfer": "grey",
            "curves": [{"intensity": [0.05, 1.0], "mean": 0.7, "width": 0.08}]}"#,
    )
    .expect("writing the OTF");
    let scene = dir.path().join("curve.json");
    std::fs::write(
        &scene,
        r#"{"version": 1, "input": {"path": "phantom:nested:48"},
            "classification": {"occlusion": "curve.otf.json"},
            "camera": {"azimuth": 0, "elevation": 20, "distance": 2.2}, "one_pass": true}"#,
    )
    .expect("writing the scene");
    let (v, before, line) = open_scene(&x, dir.path(), &scene, "760x900");
    let h = mark(&line, "curve1-mean").expect("the curve's mean handle is on screen");
    let sp = mark(&line, "spectrum").expect("the spectrum is on screen");
    // Down by a quarter of the spectrum: the mean falls by about 0.25.
    drag(
        &x,
        &v.window,
        [h[0] + h[2] / 2, h[1] + h[3] / 2],
        [0, sp[3] / 20],
        5,
        PAUSE,
    );
    let moved = rgb(&v.screenshot(&x));
    let (mean, _) = difference(&before, &moved);
    assert!(
        mean > 0.5,
        "moving the curve did not change the image ({mean:.3})"
    );
    xdotool(&x, &["key", "ctrl+s"]);
    let otf = dir.path().join("vellum.scene.otf.json");
    let deadline = Instant::now() + Duration::from_secs(60);
    while !otf.exists() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(100));
    }
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&otf).expect("reading the OTF"))
            .expect("the OTF is JSON");
    let m = written["curves"][0]["mean"]
        .as_f64()
        .expect("a curve with a mean");
    assert!((0.35..0.6).contains(&m), "the mean went from 0.7 to {m}");
    v.close(&x);
}

/// The viewer on a small Shepp-Logan phantom with an opaque isosurface, and its first screenshot.
fn start_phantom(x: &Xvfb, dir: &Path, size: &str) -> (Viewer, image::RgbImage) {
    let v = start(
        x,
        dir,
        &["phantom:shepp-logan:32", "--iso", "0.9", "--size", size],
    );
    v.expect("layout view");
    let first = rgb(&v.screenshot(x));
    (v, first)
}

/// Minimised and restored through a window manager (twm, which `make deps` installs: Xvfb has
/// none), the viewer keeps running with validation silent and shows the same picture.
#[test]
fn minimise_and_restore() {
    let Some((x, _one)) = xvfb() else { return };
    if !have("twm") {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "twm is needed to minimise a window under Xvfb; `make deps` installs it"
        );
        eprintln!("skipped: twm is missing (make deps installs it)");
        return;
    }
    let dir = tempfile::tempdir().expect("a temporary folder");
    // Place windows without asking, and no title bars.
    let rc = dir.path().join("twmrc");
    std::fs::write(&rc, "RandomPlacement\nNoTitle\n").expect("writing twmrc");
    let mut wm = Command::new("twm")
        .arg("-f")
        .arg(&rc)
        .env("DISPLAY", &x.display)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("starting twm");
    std::thread::sleep(Duration::from_millis(500));
    let (v, before) = start_phantom(&x, dir.path(), "480x360");
    xdotool(&x, &["windowminimize", "--sync", &v.window]);
    std::thread::sleep(Duration::from_millis(1500));
    xdotool(&x, &["windowmap", "--sync", &v.window]);
    xdotool(&x, &["windowfocus", "--sync", &v.window]);
    std::thread::sleep(Duration::from_millis(1000));
    let after = rgb(&v.screenshot(&x));
    let (mean, max) = difference(&before, &after);
    assert!(
        mean < 0.01 && max <= 1,
        "the picture changed across minimise and restore ({mean:.3}, {max})"
    );
    v.close(&x);
    let _ = wm.kill();
    let _ = wm.wait();
}

/// A file that is not a volume, opened through the panel's path field, gets the reader's one
/// sentence in the window, and the volume on screen stays.
#[test]
fn a_bad_file_is_one_sentence_and_the_volume_stays() {
    let Some((x, _one)) = xvfb() else { return };
    let dir = tempfile::tempdir().expect("a temporary folder");
    let bad = dir.path().join("broken.nrrd");
    std::fs::write(&bad, "NRRD0004\ntype: float\ndimension: 3\nsizes: 4 4\n\n")
        .expect("writing the bad file");
    let (v, before) = start_phantom(&x, dir.path(), "720x480");
    std::thread::sleep(Duration::from_millis(1000));
    v.layout();
    let line = v.layout.borrow().clone();
    let click = |name: &str| {
        let r = mark(&line, name).unwrap_or_else(|| panic!("{name} is on screen"));
        let (cx, cy) = ((r[0] + r[2] / 2).to_string(), (r[1] + r[3] / 2).to_string());
        xdotool(&x, &["mousemove", "--window", &v.window, &cx, &cy]);
        std::thread::sleep(Duration::from_millis(300));
        xdotool(&x, &["click", "1"]);
        std::thread::sleep(Duration::from_millis(300));
    };
    click("open-path");
    xdotool(&x, &["type", "--delay", "20", bad.to_str().expect("utf-8")]);
    std::thread::sleep(Duration::from_millis(300));
    click("open-button");
    let message = v.expect(&format!("message: {}", bad.display()));
    assert!(
        message.contains("broken.nrrd") && !message.contains('\n') && message.len() < 400,
        "{message}"
    );
    let after = rgb(&v.screenshot(&x));
    let (mean, max) = difference(&before, &after);
    assert!(
        mean == 0.0 && max == 0,
        "the volume on screen changed after a failed load"
    );

    // (A volume whose textures exceed the GPU budget is no longer refused: the session streams
    // it through the brick cache, as a_store_larger_than_the_budget_streams_while_the_view_orbits
    // shows.)
    v.close(&x);
}

/// `vellum view` on `x`'s display with validation and synchronization validation on, run to
/// completion by the caller (a bench), with `dir` as the runtime folder when the session has none.
fn validated_view(x: &Xvfb, dir: &Path) -> Command {
    let mut c = Command::new(VELLUM);
    c.arg("view")
        .env("DISPLAY", &x.display)
        .env("VELLUM_VALIDATION", "1")
        .env("VELLUM_SYNC_VALIDATION", "1")
        .env(
            "XDG_RUNTIME_DIR",
            std::env::var("XDG_RUNTIME_DIR").unwrap_or_else(|_| dir.display().to_string()),
        );
    c
}

/// The JSON report of a finished `view --bench`, which must have exited cleanly with
/// validation and synchronization validation silent.
fn bench_report(out: &std::process::Output) -> serde_json::Value {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        !stderr.contains("validation layer reported") && !stderr.contains("panicked"),
        "{stderr}"
    );
    serde_json::from_slice(&out.stdout).expect("a JSON report")
}

/// `--bench` orbits a scene in style 4 as a drag does: the interactive frames extract lines by
/// the seeded traversal, seeded frame after frame with two frames in flight, with validation and
/// synchronization validation silent. The report names the passes, and `--screenshot-on-exit`
/// writes the last view, with the lines on it.
#[test]
fn the_bench_orbits_with_seeded_lines_and_writes_the_exit_screenshot() {
    let Some((x, _guard)) = xvfb() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let scene = dir.path().join("torus.json");
    let tf = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/tf_surface_only.json");
    std::fs::write(
        &scene,
        serde_json::json!({
            "version": 1,
            "input": {"path": "phantom:torus:48"},
            "classification": {"transfer": tf},
            "focus": {"iso": 0.5},
            "style": {"style": 4, "params": {"edge_color": [1.0, 0.0, 0.0], "edge_width": 2}},
        })
        .to_string(),
    )
    .unwrap();
    let shot = dir.path().join("last.png");
    let out = validated_view(&x, dir.path())
        .arg("--scene")
        .arg(&scene)
        .args(["--size", "320x240", "--bench", "4", "--json", "--no-vsync"])
        .arg("--screenshot-on-exit")
        .arg(&shot)
        .output()
        .expect("running vellum view --bench");
    let report = bench_report(&out);
    assert_eq!(report["quality"], "interactive", "{report}");
    assert!(report["fps"].as_f64().unwrap() > 0.0, "{report}");
    let passes: Vec<&str> = report["gpu_ms"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|p| p[0].as_str())
        .collect();
    assert!(
        passes.contains(&"lines") && passes.contains(&"lines_draw"),
        "{report}"
    );
    // The silhouettes are drawn in red: strongly red pixels are on the last view.
    let red = rgb(&shot)
        .pixels()
        .filter(|p| p[0] > 150 && p[1] < 80 && p[2] < 80)
        .count();
    assert!(red > 50, "{red} red pixels on the last view");
}

/// A 192³ Shepp–Logan store in `dir` (`convert`'s default pyramid), larger than 6 MiB.
fn head_store(dir: &Path) -> PathBuf {
    let store = dir.join("head.ome.zarr");
    let made = Command::new(VELLUM)
        .args(["convert", "phantom:shepp-logan:192"])
        .arg(&store)
        .output()
        .expect("running vellum convert");
    assert!(
        made.status.success(),
        "{}",
        String::from_utf8_lossy(&made.stderr)
    );
    store
}

/// `view INPUT --bench FRAMES` through a 1.5 MiB budget (16 slots) at 320×240 with `flags`: the report's
/// brick line, the report, and the lit pixels of the exit screenshot.
fn view_streamed(
    x: &Xvfb,
    dir: &Path,
    input: &str,
    frames: &str,
    flags: &[&std::ffi::OsStr],
) -> (String, serde_json::Value, usize) {
    let shot = dir.join("last.png");
    let out = validated_view(x, dir)
        .args([input, "--iso", "0.9", "--tf", "grey", "--gpu-budget", "1.5"])
        .args([
            "--size",
            "320x240",
            "--bench",
            frames,
            "--json",
            "--no-vsync",
        ])
        .args(flags)
        .arg("--screenshot-on-exit")
        .arg(&shot)
        .output()
        .expect("running vellum view --bench");
    let report = bench_report(&out);
    let line = report["streaming"]
        .as_str()
        .expect("a streamed volume's brick line")
        .to_string();
    let lit = rgb(&shot).pixels().filter(|p| p[0] > 60).count();
    (line, report, lit)
}

/// A store larger than the GPU budget opens streamed (issue 26): frames draw what is resident,
/// coarser where a brick is missing, ask for what they missed, and the loader fills the cache
/// while the orbit goes on; validation and synchronization validation stay silent with two
/// frames in flight, bricks uploaded mid-orbit and slots reused. The report carries the corner's
/// brick line and the exit screenshot shows the head.
#[test]
fn a_store_larger_than_the_budget_streams_while_the_view_orbits() {
    let Some((x, _guard)) = xvfb() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let store = head_store(dir.path());
    let log = dir.path().join("frames.csv");
    // Host memory of 2 MiB for the chunks and bricks (the store's level 0 is 27 MiB).
    let flags = [
        "--bench-log".as_ref(),
        log.as_os_str(),
        "--memory-budget".as_ref(),
        "2".as_ref(),
    ];
    let (line, report, lit) = view_streamed(&x, dir.path(), store.to_str().unwrap(), "40", &flags);
    println!("{line}; first frame {} ms", report["first_frame_ms"]);
    // `--bench-log`: a row per presented frame, the ray cast of every completed one, and what
    // the streamed frames' rays asked for.
    let csv = std::fs::read_to_string(&log).expect("the bench's frames");
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some("kind,frame,name,value"));
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    let values = |kind: &str, name: &str| -> Vec<f64> {
        rows.iter()
            .filter(|r| r[0] == kind && r[2] == name)
            .map(|r| r[3].parse().expect("a number"))
            .collect()
    };
    let presented = values("present", "frame_ms");
    assert_eq!(
        presented.len() as u64,
        report["frames_presented"].as_u64().unwrap(),
        "one row per frame presented"
    );
    assert!(presented.iter().all(|&ms| ms > 0.0), "{csv}");
    let raycast = values("gpu", "raycast");
    assert!(
        raycast.len() >= 40 && raycast.iter().all(|&ms| ms > 0.0),
        "{csv}"
    );
    let asked: f64 = values("bricks", "asked").iter().sum();
    assert!(asked > 16.0, "the frames asked for {asked} bricks");
    // "bricks R/C resident, Q requested, S streamed (M MiB)"
    let streamed: u64 = line
        .split(", ")
        .nth(2)
        .and_then(|p| p.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .expect("a streamed count");
    assert!(streamed > 16, "more bricks than slots went up: {line}");
    assert!(
        line.contains("/16 resident"),
        "1.5 MiB holds 16 slots: {line}"
    );
    assert!(lit > 2000, "{lit} lit pixels on the last view");
}

/// A store on a server whose finest chunks come back broken, then on one that stops answering
/// for them (issues 39 and 42): the viewer keeps orbiting and draws those bricks from the coarser
/// level, with validation silent.
/// - Broken chunks: its corner's line names the chunk that could not be read.
/// - Stalled chunks (each tried 4 times, `--http-timeout 1`): the view closes without waiting
///   for reads to time out, so some chunk it was reading met fewer than its 4 tries.
#[test]
fn a_server_whose_finest_chunks_break_or_stall_leaves_the_view_on_the_coarser_level() {
    let Some((x, _guard)) = xvfb() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    head_store(dir.path());
    let cache = dir.path().join("cache");
    for fault in [http_server::Fault::Garbage, http_server::Fault::Stall] {
        let server = http_server::Server::start(dir.path(), 0, move |path, _| {
            match path.contains("/0/c/") {
                true => fault,
                false => http_server::Fault::None,
            }
        });
        let url = server.url("head.ome.zarr");
        let flags = [cache.as_os_str(), "--http-timeout".as_ref(), "1".as_ref()];
        let flags = [&["--cache-dir".as_ref()], &flags[..]].concat();
        let (line, report, lit) = view_streamed(&x, dir.path(), &url, "30", &flags);
        println!("{fault:?}: {line}");
        assert!(lit > 2000, "{fault:?}: {lit} lit pixels on the last view");
        assert_eq!(report["frames"], 29, "{fault:?}: {report}");
        let fewest = server.fewest("/0/c/").expect("a finest chunk asked for");
        match fault {
            http_server::Fault::Garbage => assert!(
                line.contains("drawn from coarser levels where bricks are missing")
                    && line.contains("0/c/"),
                "the corner does not name the broken chunk: {line}"
            ),
            _ => assert!(
                fewest < 4,
                "every stalled chunk was tried 4 times: the view waited for its reads"
            ),
        }
    }
}

/// A store whose finest chunks vanish while the viewer reads it (issue 39): once the store is
/// open (the log's line that it is streamed), level 0's chunk files are deleted. The
/// view keeps orbiting on the coarser levels, its corner names a chunk that went, and the
/// finest bricks are never drawn as the fill value (air) in their place.
#[test]
fn a_store_whose_chunks_vanish_leaves_the_view_on_the_coarser_level() {
    let Some((x, _guard)) = xvfb() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let store = head_store(dir.path());
    let shot = dir.path().join("last.png");
    let mut child = validated_view(&x, dir.path())
        .arg(&store)
        .args(["--iso", "0.9", "--tf", "grey", "--gpu-budget", "6", "-v"])
        .args(["--size", "320x240", "--bench", "40", "--json", "--no-vsync"])
        .arg("--screenshot-on-exit")
        .arg(&shot)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("running vellum view --bench");
    let stderr = child.stderr.take().unwrap();
    let finest = store.join("0/c");
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stderr).lines().map_while(|l| l.ok()) {
            if line.contains("streamed through the brick cache") && finest.exists() {
                std::fs::remove_dir_all(&finest).unwrap();
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    let mut stdout = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    let status = child.wait().unwrap();
    let stderr = reader.join().unwrap();
    assert!(status.success(), "{stderr}");
    assert!(
        !store.join("0/c").exists(),
        "the store was never opened: {stderr}"
    );
    assert!(!stderr.contains("validation layer reported"), "{stderr}");
    let report: serde_json::Value = serde_json::from_str(&stdout).expect("a JSON report");
    let line = report["streaming"].as_str().expect("a brick line");
    println!("{line}");
    assert!(
        line.contains("drawn from coarser levels where bricks are missing")
            && line.contains("0/c/")
            && line.contains("is gone now"),
        "the corner does not name the vanished chunk: {line}"
    );
    let lit = rgb(&shot).pixels().filter(|p| p[0] > 60).count();
    assert!(lit > 2000, "{lit} lit pixels on the last view");
}

/// The soak: 6,000 bench frames of a small phantom, with validation and synchronization
/// validation on (20,000 until CI's time ran short; a leak of 13 bytes a frame still fails the
/// heap bound, one of 1.6 KiB the resident set's). From frame 1,000 to 6,000:
/// - the Rust heap vellum keeps (counted by the binary's allocator) stays within 64 KiB: the
///   viewer keeps nothing per frame, and the bench's own bookkeeping is a bounded window;
/// - the resident set stays within 8 MiB. It is looser because the validation layer's own
///   memory grows in 1 MiB steps, by 1 to 5 MiB over these frames from run to run (measured:
///   without validation one step, then flat), while the Rust heap stayed within 5 KiB.
#[test]
fn six_thousand_frames_hold_the_resident_set() {
    let Some((x, _guard)) = xvfb() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = validated_view(&x, dir.path())
        .args(["phantom:shepp-logan:32", "--size", "96x96"])
        .args(["--bench", "6000", "--json", "--no-vsync"])
        .output()
        .expect("running vellum view --bench");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("validation layer reported"), "{stderr}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("a JSON report");
    assert!(
        report["frames_presented"].as_u64().unwrap() >= 6_000,
        "{report}"
    );
    let rss: Vec<(u64, u64)> = report["rss_kib"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s[0].as_u64().unwrap(), s[1].as_u64().unwrap()))
        .collect();
    let at = |frame: u64| {
        rss.iter()
            .find(|(f, _)| *f == frame)
            .map(|&(_, kib)| kib)
            .unwrap_or_else(|| panic!("no sample at frame {frame}: {rss:?}"))
    };
    let (early, late) = (at(1_000), at(6_000));
    eprintln!("resident set: {early} KiB after frame 1,000, {late} KiB after frame 6,000");
    assert!(
        late <= early + 8192,
        "the resident set grew by {} KiB from frame 1,000 to 6,000: {rss:?}",
        late - early
    );
    let heap: Vec<(u64, u64)> = report["heap_bytes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s[0].as_u64().unwrap(), s[1].as_u64().unwrap()))
        .collect();
    let bytes = |frame: u64| {
        heap.iter()
            .find(|(f, _)| *f == frame)
            .map(|&(_, b)| b as i64)
    };
    let (early, late) = (bytes(1_000).unwrap(), bytes(6_000).unwrap());
    eprintln!("Rust heap: {early} bytes after frame 1,000, {late} after frame 6,000");
    assert!(
        late <= early + 65_536,
        "vellum's heap grew by {} bytes from frame 1,000 to 6,000: {heap:?}",
        late - early
    );
}

/// Issue 42 in the window: a label volume's segments draw in their colours, as `render` draws
/// them (the viewer prepares its volume itself and attaches segments through the session's
/// `attach_beside`); a click on a segment in the image picks it, and unticking it in the
/// segments panel hides it, with validation silent.
#[test]
fn segments_draw_in_their_colours_are_picked_by_a_click_and_hidden_from_the_list() {
    let Some((x, _guard)) = xvfb() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // Two boxes of ids 3 and 7 beside an intensity that is their mask.
    let n = 24;
    let mut labels = vec![0u8; n * n * n];
    for z in 6..18 {
        for y in 6..18 {
            for x in 2..22 {
                labels[x + n * (y + n * z)] = if x < 12 { 3 } else { 7 };
            }
        }
    }
    let vol = |d| vellum::volume::Volume::new([n; 3], [1.0; 3], d).unwrap();
    let mask: Vec<f32> = labels.iter().map(|&l| (l > 0) as u8 as f32).collect();
    let (img, lab) = (dir.path().join("i.nrrd"), dir.path().join("l.nrrd"));
    vellum::volume::io::write(&img, &vol(vellum::volume::VoxelData::F32(mask))).unwrap();
    vellum::volume::io::write(&lab, &vol(vellum::volume::VoxelData::U8(labels))).unwrap();
    let (img, lab) = (img.to_str().unwrap(), lab.to_str().unwrap());
    let v = start(
        &x,
        dir.path(),
        &[
            img,
            "--labels",
            lab,
            "--hide-labels",
            "0",
            "--label-colour",
            "3=#ff0000",
            "--label-colour",
            "7=#0000ff",
            "--size",
            "900x700",
        ],
    );
    v.expect("layout view");
    let red = |p: &image::Rgb<u8>| p[0] > 80 && p[0] as u32 > 3 * (p[1] as u32 + p[2] as u32);
    let blue = |p: &image::Rgb<u8>| p[2] > 80 && p[2] as u32 > 3 * (p[0] as u32 + p[1] as u32);
    let first = rgb(&v.screenshot(&x));
    let reds: Vec<(u32, u32)> = first
        .enumerate_pixels()
        .filter(|(_, _, p)| red(p))
        .map(|(x, y, _)| (x, y))
        .collect();
    let blues = first.pixels().filter(|p| blue(p)).count();
    assert!(
        reds.len() > 200 && blues > 200,
        "{} red and {blues} blue pixels",
        reds.len()
    );
    // Click the middle of the red segment: the message names label 3.
    let (view, _) = v.layout();
    let mean = |f: fn(&(u32, u32)) -> u32| reds.iter().map(f).sum::<u32>() / reds.len() as u32;
    let at = [
        view[0] + mean(|p| p.0) as i64,
        view[1] + mean(|p| p.1) as i64,
    ];
    click(&x, &v.window, at);
    let said = v.expect("message: picked");
    assert!(said.contains("picked label 3 ("), "{said}");
    // Untick label 3 in the list: no red is left, the blue stays.
    std::thread::sleep(Duration::from_millis(500));
    v.layout();
    let line = v.layout.borrow().clone();
    let b = mark(&line, "label:3").expect("label 3's box is on screen");
    click(&x, &v.window, centre(b));
    std::thread::sleep(Duration::from_millis(300));
    let hidden = rgb(&v.screenshot(&x));
    let (reds, blues) = (
        hidden.pixels().filter(|p| red(p)).count(),
        hidden.pixels().filter(|p| blue(p)).count(),
    );
    assert!(
        reds == 0 && blues > 200,
        "after hiding label 3: {reds} red and {blues} blue pixels"
    );
    v.close(&x);
}
