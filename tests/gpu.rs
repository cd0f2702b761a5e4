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

/// `record_upload_boxes` (how the brick cache's 16-bit bricks reach their slots): boxes of a
/// staging slice land at their places in a 3D image texel for texel, and a box past the image's
/// edge is refused in one sentence with nothing recorded.
#[test]
fn boxes_of_texels_land_where_they_are_sent() {
    use vellum::gpu::transfer::{readback, record_upload_boxes, TexelBox};
    use vellum::gpu::{submit_once, Access, Format, Image, ImageDesc};
    let gpu = Gpu::new();
    let ctx = &gpu.ctx;
    let desc = ImageDesc::new_3d(Format::R16_UNORM, [8, 4, 4]);
    let image = Image::new(ctx, "boxes", &desc).unwrap();
    let a: Vec<u16> = (0..27).collect();
    let b: Vec<u16> = (100..164).collect();
    submit_once(ctx, "boxes", |f| {
        let parts = [bytemuck::cast_slice(&a), bytemuck::cast_slice(&b)];
        let src = f.staging.push_parts(&parts, 16)?;
        image.transition(f.cmd, Access::TransferWrite);
        let boxes = [
            TexelBox {
                from: 0,
                origin: [0, 1, 1],
                extent: [3, 3, 3],
            },
            TexelBox {
                from: 54,
                origin: [4, 0, 0],
                extent: [4, 4, 4],
            },
        ];
        record_upload_boxes(ctx, f.cmd, src, &image, &boxes)?;
        let past = TexelBox {
            from: 0,
            origin: [6, 0, 0],
            extent: [3, 3, 3],
        };
        let refused = record_upload_boxes(ctx, f.cmd, src, &image, &[past]);
        let said = refused.err().map(|e| e.to_string()).unwrap_or_default();
        assert!(
            said.contains("lies outside") && !said.contains('\n'),
            "{said}"
        );
        Ok(())
    })
    .unwrap();
    let bytes = readback(ctx, &image).unwrap();
    let at = |x: usize, y: usize, z: usize| {
        let i = 2 * (x + 8 * (y + 4 * z));
        u16::from_le_bytes([bytes[i], bytes[i + 1]])
    };
    for z in 0..3 {
        for y in 0..3 {
            for x in 0..3 {
                assert_eq!(at(x, y + 1, z + 1), a[x + 3 * (y + 3 * z)], "{x} {y} {z}");
            }
        }
    }
    for z in 0..4 {
        for y in 0..4 {
            for x in 0..4 {
                assert_eq!(at(x + 4, y, z), b[x + 4 * (y + 4 * z)], "{x} {y} {z}");
            }
        }
    }
}
