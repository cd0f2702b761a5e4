//! The GPU layer on lavapipe with validation on: the messenger counts, volumes of every voxel type
//! survive a round trip bit for bit, and device problems become sentences.

mod common;

use ash::vk;
use common::Gpu;
use vellum::gpu::{Context, ContextDesc};
use vellum::passes::volume_image::round_trip;
use vellum::volume::{Volume, VoxelData};

#[test]
fn messenger_counts_a_deliberately_invalid_call() {
    let ctx = Context::new(&ContextDesc {
        validation: Some(true),
        device: None,
    })
    .expect("context");
    assert_eq!(ctx.messages().errors, 0);
    // A buffer with no usage flags violates VUID-VkBufferCreateInfo-usage-requiredbitmask.
    let info = vk::BufferCreateInfo::default()
        .size(64)
        .usage(vk::BufferUsageFlags::empty());
    unsafe {
        if let Ok(b) = ctx.device.create_buffer(&info, None) {
            ctx.device.destroy_buffer(b, None);
        }
    }
    let m = ctx.messages();
    assert!(
        m.errors >= 1,
        "the validation layer should have reported the invalid call: {m:?}"
    );
    assert!(m.messages.iter().any(|t| t.contains("usage")), "{m:?}");
}

fn volumes_of_every_type() -> Vec<Volume> {
    // Odd sizes on purpose, and values that cover each type's extremes.
    let dims = [13, 7, 5];
    let n = 13 * 7 * 5;
    vec![
        Volume::new(
            dims,
            [1.0; 3],
            VoxelData::U8((0..n).map(|i| (i * 37 % 256) as u8).collect()),
        )
        .unwrap(),
        Volume::new(
            dims,
            [1.0; 3],
            VoxelData::U16((0..n).map(|i| (i as u32 * 4099 % 65536) as u16).collect()),
        )
        .unwrap(),
        Volume::new(
            dims,
            [1.0; 3],
            VoxelData::I16((0..n).map(|i| (i * 4099 % 65536 - 32768) as i16).collect()),
        )
        .unwrap(),
        Volume::new(
            dims,
            [1.0; 3],
            VoxelData::F32(
                (0..n)
                    .map(|i| (i as f32 * 0.37).sin() * 1e6 + f32::MIN_POSITIVE)
                    .collect(),
            ),
        )
        .unwrap(),
    ]
}

#[test]
fn every_voxel_type_round_trips_bit_exact() {
    let gpu = Gpu::new();
    for v in volumes_of_every_type() {
        let r = round_trip(&gpu.ctx, &v).expect("round trip");
        assert!(r.bit_exact, "{:?} changed on the GPU", v.voxel_type());
        assert_eq!(r.bytes, v.len() * v.voxel_type().size());
        assert_eq!(
            r.passes.iter().map(|p| p.name.as_str()).collect::<Vec<_>>(),
            ["upload", "readback"]
        );
    }
}

#[test]
fn real_volume_round_trips_bit_exact() {
    let Some(v) = common::real_volume("tooth16") else {
        return;
    };
    let gpu = Gpu::new();
    assert!(round_trip(&gpu.ctx, &v).unwrap().bit_exact);
}

#[test]
fn volume_beyond_the_device_limit_is_refused() {
    let gpu = Gpu::new();
    let too_long = gpu.ctx.info.max_image_dimension_3d as usize + 1;
    let v = Volume::new([too_long, 1, 1], [1.0; 3], VoxelData::U8(vec![0; too_long])).unwrap();
    let err = round_trip(&gpu.ctx, &v)
        .expect_err("must be refused")
        .to_string();
    assert!(err.contains("at most"), "{err}");
}

#[test]
fn device_selection_by_name_and_index() {
    let default = Context::new(&ContextDesc {
        validation: Some(true),
        device: None,
    })
    .unwrap();
    let part: String = default.info.name.to_uppercase().chars().take(5).collect();
    let by_name = Context::new(&ContextDesc {
        validation: Some(true),
        device: Some(part),
    })
    .unwrap();
    assert_eq!(by_name.info.name, default.info.name);
    let by_index = Context::new(&ContextDesc {
        validation: Some(true),
        device: Some(default.chosen.to_string()),
    })
    .unwrap();
    assert_eq!(by_index.info.name, default.info.name);
    let err = Context::new(&ContextDesc {
        validation: Some(true),
        device: Some("no-such-gpu".into()),
    })
    .unwrap_err()
    .to_string();
    assert!(err.contains("no device matches 'no-such-gpu'"), "{err}");
}
