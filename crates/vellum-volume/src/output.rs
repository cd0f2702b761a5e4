//! Writing result files without ever leaving a partial one behind.
//!
//! ## One file
//! Everything is written under a temporary name in the destination folder (`.vellum.PID.N.tmp`,
//! short so that a name near the file-system limit still fits), flushed to disk, and renamed into
//! place only once complete.
//!
//! ## All of a command's files, or none
//! Between [`begin`] and [`commit`], completed files stay under their temporary names: `commit`
//! renames them all, and [`abort`] (or an error, or Ctrl-C through [`remove_pending_and_exit`]) removes them
//! all. A command therefore writes every output or none, and two outputs with the same path are
//! refused. Outside a transaction (library use, tests) each file is renamed as soon as it is
//! complete.
//!
//! ## Special paths
//! Only regular files are replaced: an output path that exists and is a device, FIFO, socket or
//! folder, or a symbolic link, is refused with a sentence (rename would replace the node itself,
//! not write through it).
//!
//! Formats: 8-bit PNG for looking at, multi-layer float OpenEXR for post-processing (one file holds
//! every render target of a frame as named layers, so researchers can recombine them).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use vellum_error::{Error, Result};

/// Completed temporary files waiting for [`commit`], as (temporary, final) paths; `None` when no
/// transaction is open.
static PENDING: Mutex<Option<Vec<(PathBuf, PathBuf)>>> = Mutex::new(None);
/// Temporary files being written right now (removed on Ctrl-C too).
static WRITING: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());
static COUNTER: AtomicU64 = AtomicU64::new(0);

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Opens a transaction: files written from now on are renamed into place by [`commit`].
pub fn begin() {
    *lock(&PENDING) = Some(Vec::new());
}

/// Renames every completed file into place and closes the transaction.
pub fn commit() -> Result<()> {
    let pending = lock(&PENDING).take().unwrap_or_default();
    for (i, (tmp, path)) in pending.iter().enumerate() {
        if let Err(e) = std::fs::rename(tmp, path) {
            // Nothing sensible is left to do with the rest: remove them, report this one.
            for (t, _) in &pending[i..] {
                remove(t);
            }
            return Err(Error::io(path, e));
        }
    }
    Ok(())
}

/// Removes every completed file of the transaction and closes it.
pub fn abort() {
    if let Some(pending) = lock(&PENDING).take() {
        for (tmp, _) in pending {
            remove(&tmp);
        }
    }
}

/// Removes every temporary file, complete or being written, then ends the process with `code`, still holding the list of files
/// being written: once interrupted, no thread can make a new temporary after the removal
/// (`begin_folder` and [`write_atomic`] make theirs under that lock, after checking
/// [`vellum_error::check_interrupt`]).
pub fn remove_pending_and_exit(code: i32) -> ! {
    let writing = lock(&WRITING);
    for tmp in writing.iter() {
        remove(tmp);
    }
    abort();
    std::process::exit(code)
}

/// Waits until no temporary file or folder is being written (the writers, told by
/// [`vellum_error::interrupt`], stop at their next chunk and remove their own), or `limit`
/// has passed.
pub fn wait_for_writers(limit: std::time::Duration) {
    let until = std::time::Instant::now() + limit;
    while !lock(&WRITING).is_empty() && std::time::Instant::now() < until {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

/// Removes a temporary file, or a temporary folder and what it holds.
fn remove(tmp: &Path) {
    if tmp.is_dir() {
        let _ = std::fs::remove_dir_all(tmp);
    } else {
        let _ = std::fs::remove_file(tmp);
    }
}

/// A folder output (a chunked store) written as [`write_atomic`] writes a file, under its
/// temporary name: [`begin_folder`], filling [`FolderInProgress::tmp`], then
/// [`FolderInProgress::finish`], which renames it into place or removes it.
/// The split lets the ranks of a job fill one folder that rank 0 made and renames.
pub(crate) struct FolderInProgress {
    /// The temporary folder to fill; renamed to the output by `finish`.
    pub(crate) tmp: PathBuf,
    path: PathBuf,
}

/// Checks that `path` is a new folder's path and makes its temporary folder beside it.
pub(crate) fn begin_folder(path: &Path) -> Result<FolderInProgress> {
    if path.file_name().is_none() {
        return Err(Error::Invalid(format!(
            "{} has no folder name; expected a path to a new folder",
            path.display()
        )));
    }
    if std::fs::symlink_metadata(path).is_ok() {
        return Err(Error::Invalid(format!(
            "{} already exists; expected a new folder for the store",
            path.display()
        )));
    }
    let tmp = temporary_beside(path);
    let mut writing = lock(&WRITING);
    vellum_error::check_interrupt()?;
    let made = std::fs::create_dir(&tmp);
    if made.is_ok() {
        writing.push(tmp.clone());
    }
    drop(writing);
    if let Err(e) = made {
        // Named by the store the user asked for; the temporary name is ours.
        let folder = path.parent().filter(|p| !p.as_os_str().is_empty());
        let folder = folder.unwrap_or(Path::new("."));
        return Err(Error::Invalid(format!(
            "{} cannot be written: its folder {} refuses a new entry ({e})",
            path.display(),
            folder.display()
        )));
    }
    Ok(FolderInProgress {
        tmp,
        path: path.to_path_buf(),
    })
}

impl FolderInProgress {
    /// Renames the folder into place when `result` is `Ok` (at [`commit`] in a transaction), or
    /// removes it and returns the error.
    pub(crate) fn finish(self, result: Result<()>) -> Result<()> {
        // The folder leaves the list only once it is removed or handed to the transaction, both
        // under the list's lock: a signal handler never sees it in neither place.
        let mut writing = lock(&WRITING);
        let done = match result {
            Err(e) => {
                remove(&self.tmp);
                Err(e)
            }
            Ok(()) => complete(self.tmp.clone(), &self.path),
        };
        writing.retain(|t| t != &self.tmp);
        done
    }
}

/// A temporary name beside `path` (short, so that a name near the file-system limit still fits).
fn temporary_beside(path: &Path) -> PathBuf {
    if let Some(folder) = path.parent() {
        sweep_stale(if folder.as_os_str().is_empty() {
            Path::new(".")
        } else {
            folder
        });
    }
    path.with_file_name(format!(
        ".vellum.{}.{}.tmp",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ))
}

/// Removes the temporary files and folders in `folder` that a vellum process left when it was
/// killed outright (SIGKILL, a power cut: no handler ran): `.vellum.PID.N.tmp` whose process no
/// longer runs. Only where /proc tells which processes run (Linux); a live process's are kept.
fn sweep_stale(folder: &Path) {
    let proc = Path::new("/proc");
    if !proc.join("self").exists() {
        return;
    }
    let Ok(entries) = std::fs::read_dir(folder) else {
        return;
    };
    let own = std::process::id().to_string();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(rest) = name
            .strip_prefix(".vellum.")
            .and_then(|r| r.strip_suffix(".tmp"))
        else {
            continue;
        };
        let Some((pid, n)) = rest.split_once('.') else {
            continue;
        };
        let digits = |t: &str| !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit());
        if digits(pid) && digits(n) && pid != own && !proc.join(pid).exists() {
            remove(&e.path());
        }
    }
}

/// A complete temporary output: renamed into place now, or at [`commit`] in a transaction.
fn complete(tmp: PathBuf, path: &Path) -> Result<()> {
    let mut pending = lock(&PENDING);
    match pending.as_mut() {
        Some(list) => {
            list.push((tmp, path.to_path_buf()));
            Ok(())
        }
        None => std::fs::rename(&tmp, path).map_err(|e| {
            remove(&tmp);
            Error::io(path, e)
        }),
    }
}

/// Refuses `path` when it exists and is not a regular file, or is a symbolic link.
fn check_destination(path: &Path) -> Result<()> {
    match std::fs::symlink_metadata(path) {
        Err(_) => Ok(()),
        Ok(m) if m.file_type().is_symlink() => Err(Error::Invalid(format!(
            "{} is a symbolic link; vellum writes results only to regular files, so give the link's target",
            path.display()
        ))),
        Ok(m) if !m.is_file() => Err(Error::Invalid(format!(
            "{} exists and is not a regular file (a folder, device, FIFO or socket); vellum writes results only to regular files",
            path.display()
        ))),
        Ok(_) => Ok(()),
    }
}

/// Refuses an output whose extension does not name its format (`expected` without the dot).
pub fn check_extension(path: &Path, expected: &[&str], format: &str) -> Result<()> {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    if expected.iter().any(|e| name.ends_with(&format!(".{e}"))) {
        Ok(())
    } else {
        Err(Error::Invalid(format!(
            "{} does not end in .{}; it would hold {format}",
            path.display(),
            expected.join(" or .")
        )))
    }
}

/// Writes `path` through `fill`, atomically: on any error the destination is untouched and the
/// temporary file is removed. Inside a transaction ([`begin`]), the file is renamed into place
/// by [`commit`].
pub fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<()> {
    if path.file_name().is_none() {
        return Err(Error::Invalid(format!(
            "{} has no file name; expected a path to a file",
            path.display()
        )));
    }
    check_destination(path)?;
    if let Some(pending) = lock(&PENDING).as_ref() {
        if pending.iter().any(|(_, p)| p == path) {
            return Err(Error::Invalid(format!(
                "{} is given for two outputs of one command; expected a separate path for each",
                path.display()
            )));
        }
    }
    let tmp = temporary_beside(path);
    let file = {
        let mut writing = lock(&WRITING);
        vellum_error::check_interrupt()?;
        let file = File::create(&tmp);
        writing.push(tmp.clone());
        file
    };
    let result = (|| {
        let mut w = BufWriter::new(file?);
        fill(&mut w)?;
        w.flush()?;
        w.into_inner().map_err(|e| e.into_error())?.sync_all()
    })();
    let mut writing = lock(&WRITING);
    let done = match result {
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(Error::io(path, e))
        }
        Ok(()) => complete(tmp.clone(), path),
    };
    writing.retain(|t| t != &tmp);
    done
}

/// Writes an 8-bit RGB image as PNG, atomically.
pub fn write_png_rgb(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<()> {
    use image::ImageEncoder;
    check_extension(path, &["png"], "a PNG image")?;
    write_atomic(path, |w| {
        image::codecs::png::PngEncoder::new(w)
            .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
            .map_err(std::io::Error::other)
    })
}

/// The samples of one EXR layer, row-major with rows top to bottom: pixel (x, y) at `y·width + x`.
#[derive(Debug, Clone, Copy)]
pub enum ExrChannels<'a> {
    /// Straight RGBA, written as float channels R, G, B, A.
    Rgba(&'a [[f32; 4]]),
    /// One float channel Z (depth, in whatever unit the producer documents).
    Depth(&'a [f32]),
}

/// One named layer of a multi-layer EXR file, e.g. `focus.phong` or `composite`.
#[derive(Debug, Clone, Copy)]
pub struct ExrLayer<'a> {
    /// The layer name stored in the file (Latin-1, unique within the file).
    pub name: &'a str,
    /// The layer's samples.
    pub channels: ExrChannels<'a>,
}

/// Writes all `layers` of a `width`×`height` image into one multi-layer OpenEXR file (float32
/// samples, lossless ZIP compression), atomically. Each layer keeps its own name; RGBA layers have
/// channels R, G, B, A and depth layers a single channel Z.
pub fn write_exr_layers(path: &Path, width: u32, height: u32, layers: &[ExrLayer]) -> Result<()> {
    use exr::prelude::{
        AnyChannel, AnyChannels, Encoding, FlatSamples, Image, ImageAttributes, IntegerBounds,
        Layer, LayerAttributes, Text, WritableImage,
    };

    check_extension(path, &["exr"], "OpenEXR layers")?;
    let invalid = |msg: String| Error::Invalid(format!("EXR {}: {msg}", path.display()));
    let size = (width as usize, height as usize);
    let pixels = size.0 * size.1;
    if layers.is_empty() || pixels == 0 {
        return Err(invalid(format!(
            "{} layers of {width}x{height} pixels; expected at least one layer and a non-empty image",
            layers.len()
        )));
    }
    let mut exr_layers = Vec::with_capacity(layers.len());
    for (i, layer) in layers.iter().enumerate() {
        let name = Text::new_or_none(layer.name)
            .filter(|_| !layer.name.is_empty())
            .ok_or_else(|| {
                invalid(format!(
                    "layer name {:?} is not a non-empty Latin-1 string",
                    layer.name
                ))
            })?;
        if layers[..i].iter().any(|l| l.name == layer.name) {
            return Err(invalid(format!(
                "layer name {:?} appears twice; expected unique names",
                layer.name
            )));
        }
        let (len, channels) = match layer.channels {
            ExrChannels::Rgba(rgba) => (
                rgba.len(),
                ["R", "G", "B", "A"]
                    .iter()
                    .enumerate()
                    .map(|(c, n)| {
                        let samples = rgba.iter().map(|p| p[c]).collect();
                        AnyChannel::new(*n, FlatSamples::F32(samples))
                    })
                    .collect::<Vec<_>>(),
            ),
            ExrChannels::Depth(z) => (
                z.len(),
                vec![AnyChannel::new("Z", FlatSamples::F32(z.to_vec()))],
            ),
        };
        if len != pixels {
            return Err(invalid(format!(
                "layer {:?} has {len} pixels; expected {width}x{height} = {pixels}",
                layer.name
            )));
        }
        exr_layers.push(Layer::new(
            size,
            LayerAttributes::named(name),
            Encoding::SMALL_LOSSLESS,
            AnyChannels::sort(channels.into()),
        ));
    }
    let image = Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions(size)),
        exr_layers,
    );
    write_atomic(path, |w| {
        image.write().to_buffered(w).map_err(std::io::Error::other)
    })
}

/// One group of polylines in an SVG file: an id, a stroke colour (RGB in 0..1) and width in
/// pixels, and the polylines in pixel coordinates.
pub struct SvgGroup<'a> {
    /// The group's id in the SVG.
    pub id: &'a str,
    /// Stroke colour, RGB in 0..1.
    pub colour: [f32; 3],
    /// Stroke width in pixels.
    pub width: u32,
    /// The polylines, in pixel coordinates.
    pub paths: &'a [Vec<[f32; 2]>],
}

/// Writes `groups` as an SVG of `size` pixels, atomically, with `comment` at the top: each group
/// a `<g>` of round-capped, unfilled paths.
pub fn write_svg_lines(
    path: &Path,
    size: [u32; 2],
    comment: &str,
    groups: &[SvgGroup],
) -> Result<()> {
    use std::io::Write;
    let [w, h] = size;
    let hex = |c: [f32; 3]| {
        let b = c.map(|v| (v * 255.0) as u8);
        format!("#{:02x}{:02x}{:02x}", b[0], b[1], b[2])
    };
    write_atomic(path, |f| {
        writeln!(
            f,
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}">"#
        )?;
        writeln!(f, "<!-- {comment} -->")?;
        for g in groups {
            writeln!(
                f,
                r#"<g id="{}" fill="none" stroke="{}" stroke-width="{}" stroke-linecap="round" stroke-linejoin="round">"#,
                g.id,
                hex(g.colour),
                g.width
            )?;
            for piece in g.paths {
                let mut d = String::new();
                for (i, q) in piece.iter().enumerate() {
                    let op = if i == 0 { "M" } else { " L" };
                    d.push_str(&format!("{op}{:.2} {:.2}", q[0], q[1]));
                }
                writeln!(f, r#"<path d="{d}"/>"#)?;
            }
            writeln!(f, "</g>")?;
        }
        writeln!(f, "</svg>")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_killed_processs_temporaries_are_swept_and_a_live_ones_kept() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // No process has this id (Linux's ids stop at 2^22).
        let dead = d.join(".vellum.999999999.0.tmp");
        std::fs::create_dir_all(dead.join("0/c")).unwrap();
        let live = d.join(format!(".vellum.{}.77.tmp", std::process::id()));
        std::fs::write(&live, b"mine").unwrap();
        let other = d.join(".vellum.notes.tmp");
        std::fs::write(&other, b"not ours").unwrap();
        write_atomic(&d.join("x.txt"), |f| f.write_all(b"x")).unwrap();
        assert!(!dead.exists(), "a dead process's folder stays");
        assert!(live.exists() && other.exists());
    }

    #[test]
    fn exr_layers_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("layers.exr");
        let (w, h) = (3u32, 2u32);
        let rgba: Vec<[f32; 4]> = (0..6)
            .map(|i| [i as f32, 0.5, -1.0, 1.0 - 0.1 * i as f32])
            .collect();
        let depth: Vec<f32> = (0..6).map(|i| 10.0 + i as f32).collect();
        write_exr_layers(
            &path,
            w,
            h,
            &[
                ExrLayer {
                    name: "focus.phong",
                    channels: ExrChannels::Rgba(&rgba),
                },
                ExrLayer {
                    name: "focus.depth",
                    channels: ExrChannels::Depth(&depth),
                },
            ],
        )
        .unwrap();

        let image = exr::prelude::read_all_flat_layers_from_file(&path).unwrap();
        assert_eq!(image.layer_data.len(), 2);
        let layer = |name: &str| {
            image
                .layer_data
                .iter()
                .find(|l| {
                    l.attributes.layer_name.as_ref().map(|t| t.to_string())
                        == Some(name.to_string())
                })
                .unwrap_or_else(|| panic!("no layer {name}"))
        };
        let channel = |name: &str, ch: &str| -> Vec<f32> {
            let l = layer(name);
            assert_eq!(l.size, exr::prelude::Vec2(3, 2));
            let c = l
                .channel_data
                .list
                .iter()
                .find(|c| c.name.to_string() == ch)
                .unwrap_or_else(|| panic!("no channel {ch} in {name}"));
            c.sample_data.values_as_f32().collect()
        };
        let names = |name: &str| -> Vec<String> {
            layer(name)
                .channel_data
                .list
                .iter()
                .map(|c| c.name.to_string())
                .collect()
        };
        assert_eq!(names("focus.phong"), ["A", "B", "G", "R"]);
        assert_eq!(names("focus.depth"), ["Z"]);
        // Pixel (x = 2, y = 1) is index 5.
        assert_eq!(channel("focus.phong", "R")[5], 5.0);
        assert_eq!(channel("focus.phong", "G")[0], 0.5);
        assert_eq!(channel("focus.phong", "B")[3], -1.0);
        assert_eq!(channel("focus.phong", "A")[2], rgba[2][3]);
        assert_eq!(channel("focus.depth", "Z"), depth);
    }

    #[test]
    fn exr_rejects_bad_layers_and_leaves_no_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.exr");
        let short = [0.0f32; 5];
        let e = write_exr_layers(
            &path,
            3,
            2,
            &[ExrLayer {
                name: "z",
                channels: ExrChannels::Depth(&short),
            }],
        )
        .unwrap_err();
        assert!(
            matches!(e, Error::Invalid(_)) && e.to_string().contains("expected 3x2"),
            "{e}"
        );
        let twice = [0.0f32; 6];
        let layer = ExrLayer {
            name: "z",
            channels: ExrChannels::Depth(&twice),
        };
        assert!(write_exr_layers(&path, 3, 2, &[layer, layer]).is_err());
        assert!(write_exr_layers(&path, 3, 2, &[]).is_err());
        assert!(!path.exists());

        let missing = dir.path().join("no/such/folder/out.exr");
        let e = write_exr_layers(&missing, 3, 2, &[layer]).unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e}");
        assert!(!missing.exists());
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "no temp files left"
        );
    }
}
