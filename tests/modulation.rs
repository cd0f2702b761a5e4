//! Importance modulation on lavapipe with validation on:
//! - ΔD computed on the GPU from the renderer's volume texture equals the CPU reference
//!   (|Δ| ≤ 1e-5 in normalised units), and so does its max |ΔD| reduction;
//! - the GLSL modulation functions (eq. 3–6 and the stipple hash) equal their CPU twins on inputs
//!   taken from a phantom's importance map (colours and opacities within 1e-6, stipple decisions
//!   and random numbers exactly);
//! - identity: γ = 0, or k_l = k_h = 1 with t_l = 0 and t_h = 1, renders exactly the unmodulated
//!   image, bit for bit;
//! - stippling: the same seed gives the same image, another seed another; more of the sample
//!   colour is "white" as f grows; t = 0 is all white; only the two stipple colours and their
//!   blends with the background appear.

mod common;

use common::Gpu;
use vellum::classify::modulation::{
    modulate_color, modulate_opacity, stipple_is_white, stipple_random, ColorMode, ColorModulation,
    ModulateLighting, Modulation, OpacityModulation, Stipple,
};
use vellum::classify::transfer::{ControlPoint, TransferFunction};
use vellum::classify::{Classification, Focus};
use vellum::gpu::{Bind, BindingKind, Buffer, BufferDesc, ComputePipeline};
use vellum::render::camera::Camera;
use vellum::render::frame::Renderer;
use vellum::render::scene::GpuScene;
use vellum::render::targets::FrameImage;
use vellum::render::view::{Lighting, View};
use vellum::volume::{phantom, Volume, VoxelData};

fn normalised(v: &Volume) -> Volume {
    let (texels, _) = v.normalised_u16();
    let data = texels.iter().map(|&t| t as f32 / 65535.0).collect();
    Volume::new(v.dims, v.spacing, VoxelData::F32(data)).unwrap()
}

fn scene(gpu: &Gpu, v: &Volume, tf: &TransferFunction, focus: Focus, m: &Modulation) -> GpuScene {
    GpuScene::prepare(&gpu.ctx, v, &Classification::Transfer(tf.clone()), focus, m).unwrap()
}

fn render(gpu: &Gpu, s: &mut GpuScene, camera: &str, size: u32) -> FrameImage {
    let view = View {
        camera: Camera::parse(camera).unwrap(),
        size: [size, size],
        slices: None,
        one_pass: false,
        lighting: Lighting::default(),
        style: None,
        fit: false,
        raycast: None,
    };
    Renderer::new(&gpu.ctx)
        .unwrap()
        .render_frame(&s.volume, &mut s.classify, &view, true)
        .unwrap()
}

fn bits(f: &FrameImage) -> Vec<u32> {
    f.composite.iter().flatten().map(|x| x.to_bits()).collect()
}

fn active() -> Modulation {
    Modulation {
        opacity: Some(OpacityModulation {
            t_low: 1.0,
            t_high: 1.0,
            k_low: 2.0,
            k_high: 1.0,
        }),
        importance_radius: 3,
        ..Modulation::default()
    }
}

#[test]
fn gpu_delta_d_matches_the_cpu_reference() {
    let gpu = Gpu::new();
    for (name, v) in [
        ("shepp-logan 37", phantom::shepp_logan(37)),
        ("nested 30", phantom::nested(30)),
    ] {
        for r in [1, 4] {
            let m = Modulation {
                importance_radius: r,
                ..active()
            };
            let grey = TransferFunction::preset("grey").unwrap();
            let s = scene(&gpu, &v, &grey, Focus::None, &m);
            let names: Vec<&str> = s.passes.iter().map(|p| p.name.as_str()).collect();
            assert!(
                names.contains(&"pack") && names.contains(&"unpack"),
                "{names:?}"
            );
            let imp = s.volume.importance.as_ref().expect("ΔD attached");
            let got: Vec<f32> = bytemuck::pod_collect_to_vec(
                &vellum::gpu::transfer::readback(&gpu.ctx, &imp.delta_d).unwrap(),
            );
            let want =
                vellum::volume::reference::gaussian::importance_map(&normalised(&v), r).unwrap();
            let mut max_err = 0.0f64;
            for (g, w) in got.iter().zip(&want) {
                max_err = max_err.max((*g as f64 - w).abs());
            }
            assert!(max_err <= 1e-5, "{name} R={r}: max |GPU − CPU| = {max_err}");
            let max_bits: [u32; 1] = bytemuck::pod_read_unaligned(
                &vellum::gpu::transfer::readback_buffer(&gpu.ctx, &imp.max_abs).unwrap()[..4],
            );
            let gpu_max = f32::from_bits(max_bits[0]) as f64;
            let cpu_max = want.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert!(
                (gpu_max - cpu_max).abs() <= 1e-5,
                "{name} R={r}: max |ΔD| GPU {gpu_max} CPU {cpu_max}"
            );
        }
    }
}

/// Inputs and outputs of glsl/classify/probe.comp (std430).
#[repr(C)]
#[derive(Copy, Clone, bytemuck::Pod, bytemuck::Zeroable)]
struct ProbeIn {
    rgb_delta: [f32; 4],
    a_n_r: [f32; 4],
    voxel: [f32; 4],
}

#[repr(C)]
#[derive(Copy, Clone, Debug, bytemuck::Pod, bytemuck::Zeroable)]
struct ProbeOut {
    raw: [f32; 4],
    absolute: [f32; 4],
    rest: [f32; 4],
}

#[repr(C)]
#[derive(Copy, Clone, bytemuck::Pod, bytemuck::Zeroable)]
struct ProbePush {
    opacity: [f32; 4],
    params: [f32; 4],
    seed: [u32; 4],
}

#[test]
fn glsl_modulation_equals_the_cpu_reference_on_a_phantom() {
    let gpu = Gpu::new();
    let ctx = &gpu.ctx;
    let v = phantom::shepp_logan(24);
    let delta = vellum::volume::reference::gaussian::importance_map(&normalised(&v), 5).unwrap();
    let max = delta.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    let tf = TransferFunction::preset("ct-skin-bone").unwrap();
    let (norm, _) = v.normalised_u16();
    let inputs: Vec<ProbeIn> = (0..delta.len())
        .map(|i| {
            let c = tf.sample(norm[i] as f32 / 65535.0);
            let n = (delta[i].abs() / max) as f32;
            let r = ((i * 7919) % 1000) as f32 / 1000.0;
            ProbeIn {
                rgb_delta: [c[0], c[1], c[2], delta[i] as f32],
                a_n_r: [c[3], n, r, 0.0],
                voxel: [
                    (i % 24) as f32 + 0.37,
                    ((i / 24) % 24) as f32 * 0.93,
                    (i / 576) as f32 - 0.5,
                    0.0,
                ],
            }
        })
        .collect();
    let (opacity, gamma, t, f, seed) = ([0.1f32, 0.6, 3.0, 0.5], -7.5f32, 0.2f32, 6.0f32, 42u32);
    let input = Buffer::from_bytes(
        ctx,
        "probe inputs",
        ash::vk::BufferUsageFlags::STORAGE_BUFFER,
        bytemuck::cast_slice(&inputs),
    )
    .unwrap();
    let mut out_desc = BufferDesc::readback((inputs.len() * 48) as u64);
    out_desc.usage |= ash::vk::BufferUsageFlags::STORAGE_BUFFER;
    let output = Buffer::new(ctx, "probe outputs", &out_desc).unwrap();
    let pipeline = ComputePipeline::new(
        ctx,
        "classify/probe.comp",
        &[BindingKind::StorageBuffer, BindingKind::StorageBuffer],
        std::mem::size_of::<ProbePush>() as u32,
    )
    .unwrap();
    vellum::gpu::submit_once(ctx, "probe", |frame| {
        let cmd = frame.cmd;
        pipeline.dispatch(
            cmd,
            &[Bind::StorageBuffer(&input), Bind::StorageBuffer(&output)],
            &ProbePush {
                opacity,
                params: [gamma, t, f, inputs.len() as f32],
                seed: [seed, 0, 0, 0],
            },
            [(inputs.len() as u32).div_ceil(64), 1, 1],
        )?;
        vellum::gpu::commands::memory_transition(
            ctx,
            cmd,
            vellum::gpu::Access::ComputeWrite,
            vellum::gpu::Access::HostRead,
        );
        Ok(())
    })
    .unwrap();
    let outs: Vec<ProbeOut> = bytemuck::pod_collect_to_vec(output.mapped().unwrap());
    let o = OpacityModulation {
        t_low: opacity[0],
        t_high: opacity[1],
        k_low: opacity[2],
        k_high: opacity[3],
    };
    let st = Stipple {
        t,
        f,
        seed,
        white: [1.0; 3],
        black: [0.0; 3],
    };
    let (mut whites, mut cases) = (0, [0; 3]);
    for (p, g) in inputs.iter().zip(&outs) {
        let rgb = [p.rgb_delta[0], p.rgb_delta[1], p.rgb_delta[2]];
        for (mode, got) in [(ColorMode::Raw, g.raw), (ColorMode::Abs, g.absolute)] {
            let want = modulate_color(rgb, p.rgb_delta[3], &ColorModulation { mode, gamma });
            for c in 0..3 {
                assert!(
                    (got[c] - want[c]).abs() <= 1e-6,
                    "{mode:?}: {got:?} vs {want:?}"
                );
            }
        }
        let (a, n, r) = (p.a_n_r[0], p.a_n_r[1], p.a_n_r[2]);
        assert!((g.rest[0] - modulate_opacity(a, n, &o)).abs() <= 1e-6);
        let white = stipple_is_white(n, r, &st);
        assert_eq!(g.rest[1] == 1.0, white, "eq. 6 at n {n}, r {r}");
        whites += white as usize;
        assert_eq!(
            g.rest[2],
            stipple_random([p.voxel[0], p.voxel[1], p.voxel[2]], seed),
            "stipple hash at {:?}",
            p.voxel
        );
        cases[if n < o.t_low {
            0
        } else if n > o.t_high {
            2
        } else {
            1
        }] += 1;
    }
    assert!(
        cases.iter().all(|&c| c > 20),
        "every case of eq. 5 is exercised: {cases:?}"
    );
    assert!(
        whites > 100 && whites < inputs.len() - 100,
        "both stipple outcomes: {whites}"
    );
}

#[test]
fn identity_parameters_render_the_unmodulated_image() {
    let gpu = Gpu::new();
    let v = phantom::shepp_logan(40);
    let tf = TransferFunction::preset("ct-skin-bone").unwrap();
    let none = Modulation::default();
    let mut plain = scene(&gpu, &v, &tf, Focus::Iso(0.9), &none);
    let want = render(&gpu, &mut plain, "30,20,2.5", 64);
    let identities = [
        Modulation {
            color: Some(ColorModulation {
                mode: ColorMode::Raw,
                gamma: 0.0,
            }),
            ..active()
        },
        Modulation {
            color: Some(ColorModulation {
                mode: ColorMode::Abs,
                gamma: 0.0,
            }),
            lighting: ModulateLighting::Phong,
            ..active()
        },
        Modulation {
            opacity: Some(OpacityModulation {
                t_low: 0.0,
                t_high: 1.0,
                k_low: 1.0,
                k_high: 1.0,
            }),
            ..active()
        },
    ];
    for m in identities {
        let m = Modulation {
            opacity: if m.color.is_some() { None } else { m.opacity },
            ..m
        };
        let mut s = scene(&gpu, &v, &tf, Focus::Iso(0.9), &m);
        assert!(s.volume.importance.is_some());
        let got = render(&gpu, &mut s, "30,20,2.5", 64);
        assert!(bits(&got) == bits(&want), "{m:?} changed the image");
    }
    // A real modulation does change it.
    let mut s = scene(&gpu, &v, &tf, Focus::Iso(0.9), &active());
    assert!(bits(&render(&gpu, &mut s, "30,20,2.5", 64)) != bits(&want));
}

fn stippled(t: f32, f: f32, seed: u32) -> Modulation {
    Modulation {
        stipple: Some(Stipple {
            t,
            f,
            seed,
            white: [1.0, 0.0, 0.0],
            black: [0.0, 0.0, 1.0],
        }),
        importance_radius: 3,
        ..Modulation::default()
    }
}

/// The share of red (the "white" colour) in the image, and the largest green value.
fn red_share(f: &FrameImage) -> (f64, f32) {
    let (mut r, mut b, mut g) = (0.0f64, 0.0f64, 0.0f32);
    for p in &f.composite {
        r += p[0] as f64;
        b += p[2] as f64;
        g = g.max(p[1]);
    }
    (r / (r + b).max(1e-9), g)
}

#[test]
fn stippling_is_seeded_grows_with_f_and_uses_two_colours() {
    let gpu = Gpu::new();
    let v = phantom::nested(36);
    // An opaque-ish ramp, so that the front samples decide most pixels.
    let tf = TransferFunction::new(
        "ramp",
        vec![
            ControlPoint {
                x: 0.05,
                rgba: [0.8, 0.8, 0.8, 0.0],
            },
            ControlPoint {
                x: 0.3,
                rgba: [0.8, 0.8, 0.8, 0.6],
            },
        ],
    )
    .unwrap();
    let frame = |m: &Modulation| {
        let mut s = scene(&gpu, &v, &tf, Focus::None, m);
        render(&gpu, &mut s, "20,30,2.5", 64)
    };
    let a = frame(&stippled(0.5, 5.0, 1));
    let b = frame(&stippled(0.5, 5.0, 1));
    let c = frame(&stippled(0.5, 5.0, 2));
    assert!(bits(&a) == bits(&b), "the same seed gives the same image");
    assert!(bits(&a) != bits(&c), "another seed gives another image");
    let shares: Vec<f64> = [0.5, 2.0, 8.0, 32.0]
        .iter()
        .map(|&f| {
            let (share, green) = red_share(&frame(&stippled(0.9, f, 7)));
            assert_eq!(
                green, 0.0,
                "only the two stipple colours (and black) appear"
            );
            share
        })
        .collect();
    assert!(
        shares.windows(2).all(|w| w[1] > w[0]),
        "the white share grows with f: {shares:?}"
    );
    let (all_white, green) = red_share(&frame(&stippled(0.0, 0.0, 3)));
    assert_eq!(green, 0.0);
    assert!(all_white > 0.999999, "t = 0 is all white: {all_white}");
    assert!(a.composite.iter().any(|p| p[3] > 0.5));
}
