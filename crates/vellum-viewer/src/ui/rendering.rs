//! The importance-modulation and renderer panels.

use super::*;

pub(super) fn importance(ui: &mut egui::Ui, m: &mut Model) {
    use vellum_render::classify::modulation::{
        ApplyTo, ModulateLighting, OpacityModulation, Stipple,
    };
    let md = m.scene.modulation.get_or_insert_with(Modulation::default);
    // Colour (eq. 3, 4).
    let mut on = md.color.is_some();
    if ui.checkbox(&mut on, "colour by ΔD (eq. 3, 4)").changed() {
        md.color = on.then_some(ColorModulation {
            mode: ColorMode::Raw,
            gamma: 1.0,
        });
    }
    if let Some(c) = &mut md.color {
        ui.horizontal(|ui| {
            ui.radio_value(&mut c.mode, ColorMode::Raw, "ΔD (eq. 3)");
            ui.radio_value(&mut c.mode, ColorMode::Abs, "|ΔD| (eq. 4)");
        });
        ui.add(egui::Slider::new(&mut c.gamma, -4.0..=4.0).text("γ"));
        ui.horizontal(|ui| {
            ui.label("adds to");
            ui.radio_value(&mut md.lighting, ModulateLighting::Ambient, "unlit");
            ui.radio_value(&mut md.lighting, ModulateLighting::Phong, "lit");
        });
    }
    // Opacity (eq. 5).
    let mut on = md.opacity.is_some();
    if ui.checkbox(&mut on, "opacity by |ΔD| (eq. 5)").changed() {
        md.opacity = on.then_some(OpacityModulation {
            t_low: 0.1,
            t_high: 1.0,
            k_low: 1.0,
            k_high: 1.0,
        });
    }
    if let Some(o) = &mut md.opacity {
        ui.add(egui::Slider::new(&mut o.t_low, 0.0..=1.0).text("t_l"));
        ui.add(egui::Slider::new(&mut o.t_high, 0.0..=1.0).text("t_h"));
        ui.add(egui::Slider::new(&mut o.k_low, 0.0..=10.0).text("k_l"));
        ui.add(egui::Slider::new(&mut o.k_high, 0.0..=10.0).text("k_h"));
        if o.t_high < o.t_low {
            o.t_high = o.t_low;
        }
    }
    // Stippling (eq. 6).
    let mut on = md.stipple.is_some();
    if ui.checkbox(&mut on, "stipple by |ΔD| (eq. 6)").changed() {
        md.stipple = on.then_some(Stipple {
            t: 0.5,
            f: 1.0,
            seed: 0,
            white: [1.0; 3],
            black: [0.0; 3],
        });
    }
    if let Some(st) = &mut md.stipple {
        ui.add(egui::Slider::new(&mut st.t, 0.0..=1.0).text("t"));
        ui.add(egui::Slider::new(&mut st.f, 0.0..=8.0).text("f"));
        ui.add(egui::Slider::new(&mut st.seed, 0..=99).text("seed"));
        ui.horizontal(|ui| {
            ui.label("colours");
            ui.color_edit_button_rgb(&mut st.white);
            ui.color_edit_button_rgb(&mut st.black);
        });
    }
    if md.is_active() {
        ui.add(egui::Slider::new(&mut md.importance_radius, 1..=16).text("R (voxels)"))
            .on_hover_text("the Gaussian of ΔD = G∗V − V (σ = R/3); a change recomputes ΔD");
        ui.horizontal(|ui| {
            ui.label("levels");
            ui.radio_value(&mut md.apply_to, ApplyTo::Focus, "focus");
            ui.radio_value(&mut md.apply_to, ApplyTo::Context, "context");
            ui.radio_value(&mut md.apply_to, ApplyTo::Both, "both");
        });
    } else {
        // No effect: no modulation in the scene (and no ΔD to compute).
        m.scene.modulation = None;
    }
}

pub(super) fn renderer(ui: &mut egui::Ui, m: &mut Model) {
    let mut ray = m.scene.raycast.is_some();
    ui.horizontal(|ui| {
        ui.radio_value(&mut ray, false, "slicer");
        ui.radio_value(&mut ray, true, "ray caster");
    });
    match (ray, m.scene.raycast.is_some()) {
        (true, false) => {
            m.scene.raycast = Some(RayOptions {
                jitter: Some(1),
                ..RayOptions::default()
            })
        }
        (false, true) => m.scene.raycast = None,
        _ => {}
    }
    if let Some(r) = &mut m.scene.raycast {
        let mut jitter = r.jitter.is_some();
        if ui.checkbox(&mut jitter, "jitter ray starts").changed() {
            r.jitter = jitter.then_some(1);
        }
        ui.checkbox(&mut r.refine_iso, "refine the isosurface");
    }
    let two_level_possible = m.scene.style.is_none();
    ui.add_enabled(
        two_level_possible,
        egui::Checkbox::new(&mut m.scene.one_pass, "one pass (no levels)"),
    );
    let mut auto = m.scene.slices.is_none();
    ui.checkbox(&mut auto, "slices: two per voxel");
    if auto {
        m.scene.slices = None;
    } else {
        let mut n = m
            .scene
            .slices
            .unwrap_or(2 * *m.dims.iter().max().unwrap_or(&64) as u32);
        ui.add(
            egui::Slider::new(&mut n, 16..=2048)
                .logarithmic(true)
                .text("slices"),
        );
        m.scene.slices = Some(n);
    }
    let l = &mut m.scene.lighting;
    ui.add(egui::Slider::new(&mut l.ambient, 0.0..=1.0).text("ambient"));
    ui.add(egui::Slider::new(&mut l.diffuse, 0.0..=1.0).text("diffuse"));
    ui.add(egui::Slider::new(&mut l.specular, 0.0..=1.0).text("specular"));
    ui.add(egui::Slider::new(&mut l.shininess, 1.0..=128.0).text("shininess"));
    ui.horizontal(|ui| {
        ui.label("background");
        ui.color_edit_button_rgb(&mut m.scene.background);
    });
}
