//! Criterion benches of the GPU passes. Criterion's clock is replaced by the passes' own Vulkan
//! timestamps (`iter_custom`), so the figures are GPU time per pass, not wall time around a
//! submission. Run with `cargo bench`; VELLUM_DEVICE picks the device.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use std::time::Duration;
use vellum::gpu::profiler::total_ms;
use vellum::gpu::{Context, ContextDesc};
use vellum::passes::importance::{ImportanceMap, GAUSS_PASSES};
use vellum::volume::phantom;

fn importance(c: &mut Criterion) {
    let ctx = Context::new(&ContextDesc {
        validation: Some(false),
        device: None,
    })
    .expect("Vulkan device");
    let mut map = ImportanceMap::new(&ctx).expect("pipelines");
    let v = phantom::shepp_logan(128);
    let mut group = c.benchmark_group(format!("importance 128³ on {}", ctx.info.name));
    group
        .sample_size(10)
        .measurement_time(Duration::from_secs(10));
    for r in [1u32, 5, 10] {
        // Warm-up: lavapipe compiles shader variants at the first dispatch.
        map.compute(&v, r, true).expect("warm-up");
        for pass in GAUSS_PASSES.iter().chain(&["subtract", "copy"]) {
            group.bench_with_input(BenchmarkId::new(*pass, r), &r, |b, &r| {
                b.iter_custom(|iters| {
                    let mut total = 0.0;
                    for _ in 0..iters {
                        let out = map.compute(&v, r, true).expect("importance map");
                        total += total_ms(&out.passes, pass);
                    }
                    Duration::from_secs_f64(total * 1e-3)
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, importance);
criterion_main!(benches);
