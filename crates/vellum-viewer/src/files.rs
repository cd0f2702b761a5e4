//! The files the session writes: a scene (with an edited feature map, OTF or transfer function
//! beside it) and screenshots.

use crate::session::Session;
use crate::ui;
use std::path::{Path, PathBuf};
use vellum_error::{Error, Result};
use vellum_render::render::scene::ClassificationSpec;

impl Session {
    /// Saves the scene at `size`; an edited feature map, OTF or transfer function goes beside
    /// it (`NAME.features.json`, `NAME.otf.json`, `NAME.tf.json`), which the scene names.
    pub(crate) fn save_scene(&self, path: &Path, size: [u32; 2]) -> Result<()> {
        let mut scene = self.model.scene.clone();
        scene.size = size;
        let m = &self.model;
        let beside = |ext: &str, json: String| -> Result<String> {
            let p = path.with_extension(ext);
            vellum_volume::output::write_atomic(&p, |w| {
                use std::io::Write;
                writeln!(w, "{json}")
            })?;
            Ok(p.to_string_lossy().into_owned())
        };
        if let (Some(map), true) = (&m.features, m.features_edited) {
            // Hidden features are saved as shown: left out of the saved map.
            let map_path = path.with_extension("features.json");
            ui::visible_map(map, &m.hidden).save(&map_path)?;
            scene.classification =
                ClassificationSpec::Features(map_path.to_string_lossy().into_owned());
        } else if let (Some(otf), true) = (&m.otf, m.otf_edited) {
            let mut otf = otf.clone();
            if let Some(t) = &otf.transfer {
                if Path::new(t).is_file() {
                    otf.transfer = std::path::absolute(t)
                        .ok()
                        .map(|p| p.to_string_lossy().into_owned());
                }
            }
            let json = serde_json::to_string_pretty(&otf)
                .map_err(|e| Error::Invalid(format!("the OTF cannot be written as JSON: {e}")))?;
            scene.classification = ClassificationSpec::Occlusion(beside("otf.json", json)?);
        } else if m.tf_edited {
            scene.classification = ClassificationSpec::Transfer(beside("tf.json", m.tf.to_json())?);
        }
        scene.save(path)
    }
}

/// The first free `vellum-NNNN.png` in `dir`.
pub(crate) fn next_screenshot_path(dir: &Path) -> Result<PathBuf> {
    for i in 1..10000 {
        let p = dir.join(format!("vellum-{i:04}.png"));
        if !p.exists() {
            return Ok(p);
        }
    }
    Err(Error::Invalid(format!(
        "{} already holds 9999 screenshots; expected a folder with room for one more",
        dir.display()
    )))
}
