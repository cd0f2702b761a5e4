//! View-aligned proxy geometry for 3D-texture slicing.
//!
//! The slicer draws the volume as a stack of planes perpendicular to the viewing direction, each
//! clipped to the volume box and textured from the 3D texture. Drawn back to front with "over"
//! blending they composite the volume; because every plane faces the eye, the sampling distance
//! along a ray is the same for all slices (the `spacing`, which feeds opacity correction).
//!
//! ## Order and winding
//! Planes come farthest from the eye first. Every triangle is counter-clockwise as seen from the
//! eye: its right-hand normal points against `view_dir`. With the camera's y-down Vulkan
//! projection ([`crate::render::camera`]) that is front-facing under
//! `VK_FRONT_FACE_COUNTER_CLOCKWISE`.

use glam::Vec3;

/// Triangles of all slice polygons, ready for one non-indexed draw.
#[derive(Debug, Clone, Default, PartialEq)]
pub(crate) struct ProxySlices {
    /// Triangle list in world units (the box frame, centred at the origin), back to front.
    pub(crate) vertices: Vec<[f32; 3]>,
    /// Distance between neighbouring planes along the viewing direction, world units.
    pub spacing: f32,
    /// Number of planes that produced a polygon.
    pub slices: u32,
}

/// The 12 edges of a box, as pairs of corner indices; corner `i` has sign bit `k` of `i` on axis `k`.
const EDGES: [(usize, usize); 12] = [
    (0, 1),
    (2, 3),
    (4, 5),
    (6, 7), // along x
    (0, 2),
    (1, 3),
    (4, 6),
    (5, 7), // along y
    (0, 4),
    (1, 5),
    (2, 6),
    (3, 7), // along z
];

/// The nearest and farthest depth of the box `[-half_extent, +half_extent]` along the unit vector
/// `d`: the planes of a frame lie between them, plane k at `far - (k + 0.5) * spacing` with
/// `spacing = (far - near) / n_slices` (the ray caster samples the same planes).
pub(crate) fn depth_span(half_extent: Vec3, d: Vec3) -> (f32, f32) {
    let depths: [f32; 8] = std::array::from_fn(|i| {
        let sign = |k: usize| if (i >> k) & 1 == 1 { 1.0 } else { -1.0 };
        Vec3::new(
            sign(0) * half_extent.x,
            sign(1) * half_extent.y,
            sign(2) * half_extent.z,
        )
        .dot(d)
    });
    let far = depths.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let near = depths.iter().copied().fold(f32::INFINITY, f32::min);
    (near, far)
}

/// Slices the box `[-half_extent, +half_extent]` (world units) with `n_slices` planes perpendicular
/// to `view_dir` (pointing from the eye into the scene; normalised here). The planes are evenly
/// spaced between the farthest and the nearest box corner, the first half a spacing inside the
/// farthest corner, and are emitted back to front. Each plane's polygon (3 to 6 vertices) becomes
/// a triangle fan.
#[cfg(test)]
pub(crate) fn view_aligned_slices(half_extent: Vec3, view_dir: Vec3, n_slices: u32) -> ProxySlices {
    view_aligned_slices_in(
        half_extent,
        view_dir,
        n_slices,
        &[(-half_extent, half_extent)],
    )
}

/// As [`view_aligned_slices`], but only the parts of the planes inside `boxes` (min, max corners,
/// disjoint, within the volume box). The planes are those of the whole volume box, so every
/// fragment samples exactly where the whole-box geometry would; this clips a pass to the bricks
/// that can contribute to it. Within a plane the boxes do not overlap, so the output stays back to
/// front. Adjacent boxes must share corner coordinates exactly so that their edges match.
pub(crate) fn view_aligned_slices_in(
    half_extent: Vec3,
    view_dir: Vec3,
    n_slices: u32,
    boxes: &[(Vec3, Vec3)],
) -> ProxySlices {
    let d = view_dir.normalize_or_zero();
    assert!(
        d != Vec3::ZERO,
        "view_dir must be a non-zero finite vector, got {view_dir}"
    );
    let corners_of = |lo: Vec3, hi: Vec3| -> [Vec3; 8] {
        std::array::from_fn(|i| {
            let pick = |k: usize, a: f32, b: f32| if (i >> k) & 1 == 1 { b } else { a };
            Vec3::new(
                pick(0, lo.x, hi.x),
                pick(1, lo.y, hi.y),
                pick(2, lo.z, hi.z),
            )
        })
    };
    let (near, far) = depth_span(half_extent, d);
    let mut out = ProxySlices {
        spacing: if n_slices == 0 {
            0.0
        } else {
            (far - near) / n_slices as f32
        },
        ..ProxySlices::default()
    };
    // Each box's corners and their depths along d, computed once.
    let boxes: Vec<([Vec3; 8], [f32; 8], f32, f32)> = boxes
        .iter()
        .map(|&(lo, hi)| {
            let c = corners_of(lo, hi);
            let t = c.map(|p| p.dot(d));
            (
                c,
                t,
                t.iter().copied().fold(f32::INFINITY, f32::min),
                t.iter().copied().fold(f32::NEG_INFINITY, f32::max),
            )
        })
        .collect();

    // In-plane basis with u × v = −d, so increasing angle runs counter-clockwise seen from the eye.
    let u = d.any_orthonormal_vector();
    let v = (-d).cross(u);
    let merge_eps = 1e-6 * half_extent.length();
    let spacing = out.spacing;

    // The triangles of plane k, every box in order. Planes are independent, so they are cut in
    // parallel (this is the host's share of a frame: tens of thousands of clips when a pass is cut
    // to bricks) and concatenated in plane order, which keeps the output identical to a serial cut.
    let plane = |polygon: &mut Vec<Vec3>, k: u32| -> Vec<[f32; 3]> {
        let t = far - (k as f32 + 0.5) * spacing;
        let mut tris = Vec::new();
        for (corners, depths, lo, hi) in &boxes {
            if t < *lo || t > *hi {
                continue;
            }
            polygon.clear();
            for &(a, b) in &EDGES {
                let (ta, tb) = (depths[a], depths[b]);
                if ta == tb || t < ta.min(tb) || t > ta.max(tb) {
                    continue; // edge parallel to or off the plane
                }
                let p = corners[a].lerp(corners[b], (t - ta) / (tb - ta));
                // A plane through a corner meets several edges there; keep one copy.
                if polygon.iter().all(|q| q.distance(p) > merge_eps) {
                    polygon.push(p);
                }
            }
            if polygon.len() < 3 {
                continue;
            }
            let centroid = polygon.iter().copied().sum::<Vec3>() / polygon.len() as f32;
            polygon.sort_by(|p, q| {
                let angle = |w: &Vec3| {
                    let r = *w - centroid;
                    r.dot(v).atan2(r.dot(u))
                };
                angle(p).total_cmp(&angle(q))
            });
            for i in 1..polygon.len() - 1 {
                for p in [polygon[0], polygon[i], polygon[i + 1]] {
                    tris.push(p.to_array());
                }
            }
        }
        tris
    };
    use rayon::prelude::*;
    let planes: Vec<Vec<[f32; 3]>> = (0..n_slices)
        .into_par_iter()
        .map_init(|| Vec::with_capacity(12), |polygon, k| plane(polygon, k))
        .collect();
    out.vertices.reserve(planes.iter().map(Vec::len).sum());
    for tris in planes {
        if !tris.is_empty() {
            out.slices += 1;
            out.vertices.extend_from_slice(&tris);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn triangles(s: &ProxySlices) -> impl Iterator<Item = [Vec3; 3]> + '_ {
        s.vertices
            .chunks_exact(3)
            .map(|t| [t[0], t[1], t[2]].map(Vec3::from_array))
    }

    fn area(t: &[Vec3; 3]) -> f32 {
        0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()
    }

    const DIRS: [Vec3; 5] = [
        Vec3::new(0.0, 1.0, 0.0),
        Vec3::new(1.0, 1.0, 1.0),
        Vec3::new(0.3, -0.5, 0.8),
        Vec3::new(-1.0, 0.0, -2.0),
        Vec3::new(0.0, 0.0, -1.0),
    ];

    #[test]
    fn vertices_lie_on_the_box_and_their_plane() {
        let half = Vec3::new(1.0, 2.0, 0.5);
        for dir in DIRS {
            let d = dir.normalize();
            let s = view_aligned_slices(half, dir, 37);
            assert_eq!(s.vertices.len() % 3, 0);
            let far = (half * d.abs()).element_sum();
            for tri in triangles(&s) {
                for p in tri {
                    let q = p.abs() / half;
                    assert!(q.max_element() < 1.0 + 1e-5, "{p} outside the box");
                    assert!(q.max_element() > 1.0 - 1e-5, "{p} not on the box surface");
                }
                let t = tri[0].dot(d);
                for p in tri {
                    assert!((p.dot(d) - t).abs() < 1e-5, "triangle not planar along {d}");
                }
                // On one of the planes far − (k + ½)·spacing.
                let k = (far - t) / s.spacing - 0.5;
                assert!((k - k.round()).abs() < 1e-3, "depth {t} is not on a plane");
            }
        }
    }

    #[test]
    fn slices_go_back_to_front() {
        for dir in DIRS {
            let d = dir.normalize();
            let s = view_aligned_slices(Vec3::new(3.0, 1.0, 2.0), dir, 50);
            assert_eq!(s.slices, 50);
            let depths: Vec<f32> = triangles(&s)
                .map(|t| t.iter().map(|p| p.dot(d)).sum::<f32>() / 3.0)
                .collect();
            for w in depths.windows(2) {
                assert!(w[1] <= w[0] + 1e-5, "depth rises from {} to {}", w[0], w[1]);
            }
        }
    }

    #[test]
    fn triangles_are_counter_clockwise_seen_from_the_eye() {
        for dir in DIRS {
            let d = dir.normalize();
            let s = view_aligned_slices(Vec3::new(1.0, 1.5, 2.0), dir, 20);
            for t in triangles(&s) {
                let n = (t[1] - t[0]).cross(t[2] - t[0]);
                assert!(n.length() > 1e-6, "degenerate triangle {t:?}");
                assert!(n.normalize().dot(d) < -0.999, "winding {n} vs view {d}");
            }
        }
    }

    #[test]
    fn axis_views_give_full_rectangles() {
        let half = Vec3::new(1.0, 2.0, 3.0);
        for (axis, face_area, depth) in [
            (Vec3::X, 4.0 * 2.0 * 3.0, 2.0),
            (Vec3::NEG_Y, 4.0 * 1.0 * 3.0, 4.0),
            (Vec3::Z, 4.0 * 1.0 * 2.0, 6.0),
        ] {
            let s = view_aligned_slices(half, axis, 10);
            assert_eq!(s.slices, 10);
            assert!((s.spacing - depth / 10.0).abs() < 1e-6);
            assert_eq!(s.vertices.len(), 10 * 2 * 3, "two triangles per rectangle");
            for rect in s.vertices.chunks_exact(6) {
                let a: f32 = triangles(&ProxySlices {
                    vertices: rect.to_vec(),
                    ..ProxySlices::default()
                })
                .map(|t| area(&t))
                .sum();
                assert!((a - face_area).abs() < 1e-4, "{axis}: area {a}");
            }
        }
    }

    #[test]
    fn boxes_tiling_the_volume_cover_the_same_area() {
        let half = Vec3::new(0.5, 0.4, 0.3);
        let d = Vec3::new(0.3, -0.8, 0.5).normalize();
        let whole = view_aligned_slices(half, d, 40);
        // The box split into 2×3×2 bricks sharing their corner coordinates exactly.
        let split = |a: usize, n: usize, h: f32| -h + 2.0 * h * a as f32 / n as f32;
        let mut boxes = Vec::new();
        for z in 0..2 {
            for y in 0..3 {
                for x in 0..2 {
                    let lo = Vec3::new(
                        split(x, 2, half.x),
                        split(y, 3, half.y),
                        split(z, 2, half.z),
                    );
                    let hi = Vec3::new(
                        split(x + 1, 2, half.x),
                        split(y + 1, 3, half.y),
                        split(z + 1, 2, half.z),
                    );
                    boxes.push((lo, hi));
                }
            }
        }
        let bricks = view_aligned_slices_in(half, d, 40, &boxes);
        let total = |s: &ProxySlices| triangles(s).map(|t| area(&t)).sum::<f32>();
        assert!((total(&whole) - total(&bricks)).abs() < 1e-4 * total(&whole));
        assert_eq!(whole.spacing, bricks.spacing);
        assert!(view_aligned_slices_in(half, d, 40, &[]).vertices.is_empty());
    }

    #[test]
    fn no_slices_no_geometry() {
        let s = view_aligned_slices(Vec3::ONE, Vec3::Z, 0);
        assert!(s.vertices.is_empty());
        assert_eq!(s.slices, 0);
    }

    #[test]
    fn slab_volumes_add_up_to_the_box() {
        let half = Vec3::new(1.0, 0.7, 1.3);
        let volume = 8.0 * half.x * half.y * half.z;
        for dir in DIRS {
            let s = view_aligned_slices(half, dir, 200);
            let total: f32 = triangles(&s).map(|t| area(&t)).sum::<f32>() * s.spacing;
            assert!(
                (total - volume).abs() < 0.02 * volume,
                "{dir}: {total} vs {volume}"
            );
        }
    }
}
