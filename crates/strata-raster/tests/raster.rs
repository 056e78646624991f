//! The rasterizer against analytic answers: coverage, clipping, depth, shading.
//!
//! Each test builds a small frame by hand (camera, meshes) and checks the fragments the
//! rasterizer emits against values computed independently in f64 from the strata's shared conventions conventions.

use glam::{DMat4, DVec3, DVec4, Mat4, Vec3};
use strata_core::{Fragment, Material, ObjectId, PackedNormal, Shading};
use strata_raster::{DrawObject, FragmentOutput, FragmentVec, FrameInput, Rasterizer};
use strata_scene::Mesh;

// ----- helpers ----------------------------------------------------------------------------------

struct Cam {
    eye: Vec3,
    target: Vec3,
    fovy_deg: f32,
    near: f32,
    far: f32,
    width: u32,
    height: u32,
}

impl Cam {
    fn looking_down_z(width: u32, height: u32) -> Cam {
        Cam {
            eye: Vec3::ZERO,
            target: Vec3::new(0.0, 0.0, -1.0),
            fovy_deg: 60.0,
            near: 0.1,
            far: 50.0,
            width,
            height,
        }
    }

    fn view(&self) -> Mat4 {
        Mat4::look_at_rh(self.eye, self.target, Vec3::Y)
    }

    fn projection(&self) -> Mat4 {
        Mat4::perspective_rh_gl(
            self.fovy_deg.to_radians(),
            self.width as f32 / self.height as f32,
            self.near,
            self.far,
        )
    }

    /// World-space ray through the centre of pixel (x, y), in f64.
    fn ray(&self, x: u32, y: u32) -> (DVec3, DVec3) {
        let ndc_x = (f64::from(x) + 0.5) / f64::from(self.width) * 2.0 - 1.0;
        let ndc_y = 1.0 - (f64::from(y) + 0.5) / f64::from(self.height) * 2.0;
        let inv = (self.projection().as_dmat4() * self.view().as_dmat4()).inverse();
        let a = inv * DVec4::new(ndc_x, ndc_y, -1.0, 1.0);
        let b = inv * DVec4::new(ndc_x, ndc_y, 1.0, 1.0);
        let (a, b) = (a.truncate() / a.w, b.truncate() / b.w);
        (self.eye.as_dvec3(), (b - a).normalize())
    }

    /// GL window depth of a world-space point, in f64.
    fn window_depth(&self, p: DVec3) -> f64 {
        let c: DVec4 = self.projection().as_dmat4() * self.view().as_dmat4() * p.extend(1.0);
        0.5 * c.z / c.w + 0.5
    }
}

fn material(shading: Shading) -> Material {
    Material {
        color: [1.0, 0.5, 0.25, 0.5],
        shading,
    }
}

/// Rasterises meshes (with their model matrices) and returns fragments per pixel.
fn render(cam: &Cam, objects: &[(&Mesh, Mat4, Shading)]) -> Vec<Vec<Fragment>> {
    render_as(cam, objects, FragmentOutput::Shaded)
}

/// [`render`] with a choice of what the colour bytes hold.
fn render_as(
    cam: &Cam,
    objects: &[(&Mesh, Mat4, Shading)],
    output: FragmentOutput,
) -> Vec<Vec<Fragment>> {
    let input = FrameInput {
        width: cam.width,
        height: cam.height,
        view: cam.view(),
        projection: cam.projection(),
        background: [1.0; 3],
        objects: objects
            .iter()
            .enumerate()
            .map(|(i, (m, model, shading))| DrawObject {
                positions: m.positions(),
                normals: m.normals(),
                triangles: m.triangles(),
                model: *model,
                material: material(*shading),
                id: ObjectId(i as u32),
            })
            .collect(),
        output,
    };
    let mut raster = Rasterizer::default();
    let prepared = raster.prepare(&input);
    let mut out = FragmentVec::new();
    let stats = prepared.rasterize(&mut out);
    assert_eq!(stats.fragments as usize, out.len());
    out.per_pixel(input.pixel_count())
}

fn mesh(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Mesh {
    Mesh::new(positions, None, triangles).expect("valid test mesh")
}

/// A `n × n` grid over `[-s, s]²` at depth `z`, interior vertices jittered deterministically
/// (so edges run at arbitrary angles), every vertex shared by its neighbouring triangles.
fn jittered_grid(n: u32, s: f32, z: f32, jitter: f32) -> Mesh {
    let mut positions = Vec::new();
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut rand = || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5
    };
    let step = 2.0 * s / n as f32;
    for j in 0..=n {
        for i in 0..=n {
            let interior = i > 0 && i < n && j > 0 && j < n;
            let (dx, dy) = if interior {
                (rand() * jitter * step, rand() * jitter * step)
            } else {
                (0.0, 0.0)
            };
            positions.push([-s + i as f32 * step + dx, -s + j as f32 * step + dy, z]);
        }
    }
    let mut triangles = Vec::new();
    let row = n + 1;
    for j in 0..n {
        for i in 0..n {
            let a = j * row + i;
            // Alternate the diagonal so vertices have different valences.
            if (i + j) % 2 == 0 {
                triangles.push([a, a + 1, a + row + 1]);
                triangles.push([a, a + row + 1, a + row]);
            } else {
                triangles.push([a, a + 1, a + row]);
                triangles.push([a + 1, a + row + 1, a + row]);
            }
        }
    }
    // No fold-overs: every triangle keeps the orientation of the unjittered grid, so any pixel
    // covered twice is a rasterizer bug, not overlapping geometry.
    for t in &triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let cross = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
        assert!(cross > 0.0, "jitter {jitter} folded a triangle over");
    }
    mesh(positions, triangles)
}

// ----- coverage ---------------------------------------------------------------------------------

#[test]
fn screen_covering_mesh_of_small_triangles_gives_exactly_one_fragment_per_pixel() {
    // 80 × 80 quads (12,800 triangles, ~3 px each at 160×120) over a square larger than the view.
    let cam = Cam::looking_down_z(160, 120);
    let grid = jittered_grid(80, 2.0, -1.5, 0.5);
    let per_pixel = render(&cam, &[(&grid, Mat4::IDENTITY, Shading::Unlit)]);
    let holes = per_pixel.iter().filter(|l| l.is_empty()).count();
    let doubles = per_pixel.iter().filter(|l| l.len() > 1).count();
    assert_eq!(
        (holes, doubles),
        (0, 0),
        "watertightness: {holes} holes, {doubles} double hits"
    );
}

/// Three copies of a screen-covering grid of micro-triangles at three depths, interleaved
/// triangle by triangle (copy 0, 1, 2 of the first triangle, then of the second, …), seen
/// through an orthographic camera so that the copies cover exactly the same pixels. The three
/// fragments a pixel receives then come from consecutive primitives, mostly of one setup batch,
/// and must arrive in primitive order: nearest copy first. Setup shades a batch's
/// micro-triangles together and hands their fragments on in one loop; this pins that the loop
/// keeps primitive order within a batch, which nothing downstream would restore. Whatever the
/// chunk size, so batches start at every offset.
#[test]
fn a_pixel_receives_the_fragments_of_one_batch_in_primitive_order() {
    let grid = jittered_grid(80, 2.0, 0.0, 0.5);
    let n = grid.positions().len() as u32;
    let mut positions = Vec::new();
    for z in [-1.5f32, -1.6, -1.7] {
        positions.extend(grid.positions().iter().map(|p| [p[0], p[1], z]));
    }
    let triangles: Vec<[u32; 3]> = grid
        .triangles()
        .iter()
        .flat_map(|t| (0..3).map(move |copy| t.map(|i| i + copy * n)))
        .collect();
    let layers = mesh(positions, triangles);
    let (width, height) = (160, 120);
    let input = FrameInput {
        width,
        height,
        view: Mat4::IDENTITY,
        // 50 pixels a unit: the grid's triangles span about 2.5 pixels.
        projection: Mat4::orthographic_rh_gl(-1.6, 1.6, -1.2, 1.2, 0.1, 50.0),
        background: [1.0; 3],
        objects: vec![DrawObject {
            positions: layers.positions(),
            normals: layers.normals(),
            triangles: layers.triangles(),
            model: Mat4::IDENTITY,
            material: material(Shading::Headlight),
            id: ObjectId(0),
        }],
        output: FragmentOutput::Shaded,
    };
    for chunk_triangles in [1, 5, 16 * 1024] {
        let mut raster = Rasterizer::new(strata_raster::RasterConfig {
            strip_height: 16,
            chunk_triangles,
        });
        let prepared = raster.prepare(&input);
        let stats = prepared.setup_stats();
        // Every fragment is a micro-triangle's (none binned for the scan).
        assert!(
            stats.micro_triangles > 10_000 && stats.bin_entries == 0,
            "micro-triangles only: {stats:?}"
        );
        let mut out = FragmentVec::new();
        prepared.rasterize(&mut out);
        let per_pixel = out.per_pixel(input.pixel_count());
        let mut out_of_order = 0;
        for (p, list) in per_pixel.iter().enumerate() {
            assert_eq!(list.len(), 3, "pixel {p}: {} fragments", list.len());
            out_of_order +=
                usize::from(!(list[0].depth < list[1].depth && list[1].depth < list[2].depth));
        }
        assert_eq!(
            out_of_order, 0,
            "chunks of {chunk_triangles}: pixels whose fragments are not in primitive order"
        );
    }
}

#[test]
fn watertight_from_many_viewpoints_and_orientations() {
    let grid = jittered_grid(40, 1.5, 0.0, 0.5);
    for (k, (rx, ry, dist)) in [
        (0.0f32, 0.0f32, 1.2f32),
        (25.0, -30.0, 1.0),
        (-50.0, 10.0, 1.1),
        (70.0, 65.0, 0.9),
    ]
    .into_iter()
    .enumerate()
    {
        let cam = Cam::looking_down_z(97, 61);
        let model = Mat4::from_translation(Vec3::new(0.0, 0.0, -dist))
            * Mat4::from_rotation_x(rx.to_radians())
            * Mat4::from_rotation_y(ry.to_radians());
        let per_pixel = render(&cam, &[(&grid, model, Shading::Unlit)]);
        assert!(
            per_pixel.iter().all(|l| l.len() <= 1),
            "view {k}: a pixel was covered twice by one surface"
        );
        // Compare with the analytic coverage of the grid's outer square (the union of the
        // triangles): pixels clearly inside must have exactly one fragment.
        let inv = model.as_dmat4().inverse();
        let mut checked = 0;
        for y in 0..cam.height {
            for x in 0..cam.width {
                let (o, d) = cam.ray(x, y);
                let (o, d) = (inv.transform_point3(o), inv.transform_vector3(d));
                if d.z.abs() < 1e-9 {
                    continue;
                }
                let t = -o.z / d.z;
                let h = o + d * t;
                if t > 0.2 && h.x.abs() < 1.45 && h.y.abs() < 1.45 {
                    checked += 1;
                    assert_eq!(
                        per_pixel[(y * cam.width + x) as usize].len(),
                        1,
                        "view {k}: hole at ({x}, {y})"
                    );
                }
            }
        }
        assert!(checked > 500, "view {k}: only {checked} pixels checked");
    }
}

#[test]
fn degenerate_and_between_centre_triangles_make_no_fragments() {
    let cam = Cam::looking_down_z(64, 48);
    let tiny = 1e-4f32;
    let m = mesh(
        vec![
            [0.0, 0.0, -1.0],
            [0.3, 0.1, -1.0],
            [0.6, 0.2, -1.0], // collinear with the first two
            [0.1, 0.1, -1.0],
            [0.1 + tiny, 0.1, -1.0],
            [0.1, 0.1 + tiny, -1.0], // far smaller than a pixel, between centres
        ],
        vec![[0, 1, 2], [0, 0, 1], [3, 3, 3], [3, 4, 5]],
    );
    let per_pixel = render(&cam, &[(&m, Mat4::IDENTITY, Shading::Unlit)]);
    assert_eq!(per_pixel.iter().map(Vec::len).sum::<usize>(), 0);
}

#[test]
fn sub_pixel_triangle_around_a_pixel_centre_makes_exactly_one_fragment() {
    let cam = Cam::looking_down_z(64, 48);
    // Find the world point behind the centre of pixel (20, 30) at depth 1 and put a triangle
    // a fifth of a pixel wide around it.
    let (o, d) = cam.ray(20, 30);
    let c = o + d * (1.0 / -d.z);
    let px = 2.0 * (30f64.to_radians()).tan() / 48.0; // one pixel at distance 1
    let r = (px * 0.2) as f32;
    let c = c.as_vec3();
    let m = mesh(
        vec![
            [c.x - r, c.y - r, c.z],
            [c.x + r, c.y - r, c.z],
            [c.x, c.y + r, c.z],
        ],
        vec![[0, 1, 2]],
    );
    let per_pixel = render(&cam, &[(&m, Mat4::IDENTITY, Shading::Unlit)]);
    let covered: Vec<usize> = (0..per_pixel.len())
        .filter(|&p| !per_pixel[p].is_empty())
        .collect();
    assert_eq!(covered, vec![30 * 64 + 20]);
}

// ----- clipping ---------------------------------------------------------------------------------

#[test]
fn floor_crossing_the_near_plane_and_passing_behind_the_eye_is_clipped_exactly() {
    // A floor y = -0.5 from z = +20 (behind the eye) to z = -20, as two huge triangles. Vertices
    // behind the eye project to nonsense; only exact clipping gets the picture right: the floor
    // below the horizon, nothing above it, nothing beyond the floor's far edge.
    let cam = Cam::looking_down_z(120, 90);
    let s = 20.0;
    let floor = mesh(
        vec![[-s, -0.5, s], [s, -0.5, s], [s, -0.5, -s], [-s, -0.5, -s]],
        vec![[0, 1, 2], [0, 2, 3]],
    );
    let per_pixel = render(&cam, &[(&floor, Mat4::IDENTITY, Shading::Unlit)]);
    let mut checked = 0;
    for y in 0..cam.height {
        for x in 0..cam.width {
            let frags = &per_pixel[(y * cam.width + x) as usize];
            let (o, d) = cam.ray(x, y);
            let hit = (d.y < 0.0).then(|| o + d * ((-0.5 - o.y) / d.y));
            let expected = match hit {
                Some(h) if h.x.abs() < s as f64 - 0.05 && h.z.abs() < s as f64 - 0.05 => Some(h),
                Some(h) if h.x.abs() < s as f64 + 0.05 && h.z.abs() < s as f64 + 0.05 => continue, // on the edge
                _ => None,
            };
            checked += 1;
            match expected {
                None => assert!(
                    frags.is_empty(),
                    "({x}, {y}): fragment where the floor is not"
                ),
                Some(h) => {
                    assert_eq!(frags.len(), 1, "({x}, {y}): floor missing");
                    let want = cam.window_depth(h);
                    assert!(
                        (f64::from(frags[0].depth) - want).abs() < 2e-5,
                        "({x}, {y}): depth {} vs {want}",
                        frags[0].depth
                    );
                }
            }
        }
    }
    assert!(checked > cam.width as usize * cam.height as usize * 9 / 10);
}

#[test]
fn triangle_entirely_behind_the_eye_makes_nothing() {
    let cam = Cam::looking_down_z(64, 48);
    let m = mesh(
        vec![[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]],
        vec![[0, 1, 2]],
    );
    let per_pixel = render(&cam, &[(&m, Mat4::IDENTITY, Shading::Unlit)]);
    assert!(per_pixel.iter().all(Vec::is_empty));
}

#[test]
fn geometry_between_eye_and_near_plane_is_cut_at_depth_zero() {
    // A wall facing the camera at distance 0.05 (< near = 0.1) is clipped away entirely; a
    // wall slanting through the near plane keeps only the part beyond it, all depths ≥ 0.
    let cam = Cam::looking_down_z(64, 48);
    let wall = mesh(
        vec![[-1.0, -1.0, -0.05], [1.0, -1.0, -0.05], [0.0, 1.0, -0.05]],
        vec![[0, 1, 2]],
    );
    assert!(
        render(&cam, &[(&wall, Mat4::IDENTITY, Shading::Unlit)])
            .iter()
            .all(Vec::is_empty)
    );
    let slant = mesh(
        vec![[-0.2, -1.0, 0.0], [-0.2, 1.0, 0.0], [0.2, 0.0, -1.0]],
        vec![[0, 1, 2]],
    );
    let per_pixel = render(&cam, &[(&slant, Mat4::IDENTITY, Shading::Unlit)]);
    let frags: Vec<_> = per_pixel.iter().flatten().collect();
    assert!(!frags.is_empty());
    assert!(
        frags
            .iter()
            .all(|f| (0.0..=1.0).contains(&f.depth) && f.depth.is_sign_positive())
    );
}

#[test]
fn fragments_beyond_the_far_plane_are_discarded() {
    let cam = Cam::looking_down_z(64, 48); // far = 50
    let big = 100.0;
    let beyond = mesh(
        vec![[-big, -big, -60.0], [big, -big, -60.0], [0.0, big, -60.0]],
        vec![[0, 1, 2]],
    );
    assert!(
        render(&cam, &[(&beyond, Mat4::IDENTITY, Shading::Unlit)])
            .iter()
            .all(Vec::is_empty)
    );
    // A floor running out past the far plane stops where depth reaches 1.
    let floor = mesh(
        vec![
            [-5.0, -0.5, -1.0],
            [5.0, -0.5, -1.0],
            [5.0, -0.5, -100.0],
            [-5.0, -0.5, -100.0],
        ],
        vec![[0, 1, 2], [0, 2, 3]],
    );
    let frags: Vec<Fragment> = render(&cam, &[(&floor, Mat4::IDENTITY, Shading::Unlit)])
        .into_iter()
        .flatten()
        .collect();
    assert!(!frags.is_empty() && frags.iter().all(|f| f.depth <= 1.0));
}

// ----- attributes -------------------------------------------------------------------------------

#[test]
fn depth_is_the_gl_window_depth_of_the_surface() {
    // A slanted plane: depth varies non-linearly in eye space but affinely in screen space.
    let cam = Cam::looking_down_z(80, 60);
    let m = mesh(
        vec![[-3.0, -3.0, -1.0], [3.0, -3.0, -1.0], [0.0, 3.0, -6.0]],
        vec![[0, 1, 2]],
    );
    let per_pixel = render(&cam, &[(&m, Mat4::IDENTITY, Shading::Unlit)]);
    let (a, b, c) = (
        DVec3::new(-3.0, -3.0, -1.0),
        DVec3::new(3.0, -3.0, -1.0),
        DVec3::new(0.0, 3.0, -6.0),
    );
    let n = (b - a).cross(c - a);
    let mut checked = 0;
    for y in 0..cam.height {
        for x in 0..cam.width {
            if let [f] = per_pixel[(y * cam.width + x) as usize].as_slice() {
                let (o, d) = cam.ray(x, y);
                let t = (a - o).dot(n) / d.dot(n);
                let want = cam.window_depth(o + d * t);
                assert!(
                    (f64::from(f.depth) - want).abs() < 1e-5,
                    "({x}, {y}): {} vs {want}",
                    f.depth
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 1000);
}

#[test]
fn headlight_uses_the_perspective_correct_position() {
    // A plane at 60° to the view: |N·L| varies across the image with the true eye-space position
    // of each sample; affine (screen-space) interpolation of the position would be visibly off.
    let cam = Cam::looking_down_z(80, 60);
    let model = Mat4::from_translation(Vec3::new(0.0, 0.0, -2.0))
        * Mat4::from_rotation_y(60f32.to_radians());
    let quad = mesh(
        vec![
            [-4.0, -4.0, 0.0],
            [4.0, -4.0, 0.0],
            [4.0, 4.0, 0.0],
            [-4.0, 4.0, 0.0],
        ],
        vec![[0, 1, 2], [0, 2, 3]],
    );
    let per_pixel = render(&cam, &[(&quad, model, Shading::Headlight)]);
    let m: DMat4 = model.as_dmat4();
    let n = m.transform_vector3(DVec3::Z).normalize();
    let p0 = m.transform_point3(DVec3::ZERO);
    let rgb = [1.0f64, 0.5, 0.25];
    let mut checked = 0;
    for y in 0..cam.height {
        for x in 0..cam.width {
            if let [f] = per_pixel[(y * cam.width + x) as usize].as_slice() {
                let (o, d) = cam.ray(x, y);
                let t = (p0 - o).dot(n) / d.dot(n);
                let p = o + d * t;
                let cos = n.dot(-p.normalize()).abs();
                let k = 0.25 + 0.75 * cos;
                for (ch, c) in rgb.iter().enumerate() {
                    let want = c * k * 255.0;
                    assert!(
                        (f64::from(f.color.0[ch]) - want).abs() <= 0.51,
                        "({x}, {y}) channel {ch}: {} vs {want:.2}",
                        f.color.0[ch]
                    );
                }
                assert_eq!(f.color.0[3], 128);
                checked += 1;
            }
        }
    }
    assert!(checked > 1000);
}

#[test]
fn unlit_fragments_carry_the_object_colour_and_id() {
    let cam = Cam::looking_down_z(32, 24);
    let quad = jittered_grid(2, 0.3, -1.0, 0.0);
    let per_pixel = render(
        &cam,
        &[
            (&quad, Mat4::IDENTITY, Shading::Unlit),
            (
                &quad,
                Mat4::from_translation(Vec3::new(0.0, 0.0, -0.5)),
                Shading::Unlit,
            ),
        ],
    );
    let centre = &per_pixel[(12 * 32 + 16) as usize];
    assert_eq!(centre.len(), 2);
    assert_eq!(centre[0].color.0, [255, 128, 64, 128]);
    // Primitive order within a pixel: object 0 first (both in one strip, one thread).
    assert_eq!(
        (centre[0].object, centre[1].object),
        (ObjectId(0), ObjectId(1))
    );
    assert!(centre[0].depth < centre[1].depth);
}

/// A `w` × `h` frame of one unlit object, `mesh` placed by `model`, seen by
/// [`Cam::looking_down_z`].
fn unlit_frame(mesh: &Mesh, model: Mat4, w: u32, h: u32) -> FrameInput<'_> {
    let cam = Cam::looking_down_z(w, h);
    FrameInput {
        width: w,
        height: h,
        view: cam.view(),
        projection: cam.projection(),
        background: [1.0; 3],
        objects: vec![DrawObject {
            positions: mesh.positions(),
            normals: mesh.normals(),
            triangles: mesh.triangles(),
            model,
            material: material(Shading::Unlit),
            id: ObjectId(0),
        }],
        output: FragmentOutput::Shaded,
    }
}

#[test]
fn rasterizer_buffers_are_reused_across_frames_of_different_sizes() {
    let grid = jittered_grid(20, 40.0, -1.5, 0.5);
    let mut raster = Rasterizer::default();
    for (w, h) in [(64, 48), (200, 10), (7, 300), (64, 48)] {
        let input = unlit_frame(&grid, Mat4::IDENTITY, w, h);
        let mut out = FragmentVec::new();
        raster.prepare(&input).rasterize(&mut out);
        assert_eq!(
            out.len(),
            (w * h) as usize,
            "{w}x{h}: every pixel exactly once"
        );
    }
}

/// A frame as wide as the rasterizer takes is covered exactly: its vertices' window coordinates
/// reach the largest fixed-point values the vertex stage's snapping must handle.
#[test]
fn the_widest_image_is_covered_exactly_and_a_wider_one_is_refused() {
    use strata_raster::vertex::MAX_SIDE;
    let grid = jittered_grid(20, 40.0, -1.5, 0.5);
    let frame = |w: u32, h: u32| {
        // The grid stretched to just past the long side of the view, so that its outer
        // vertices lie beyond the image but inside the guard band.
        let model = if w > h {
            Mat4::from_scale(Vec3::new(w as f32 / h as f32 / 40.0, 1.0, 1.0))
        } else {
            Mat4::from_scale(Vec3::new(1.0, 1.0 / 40.0, 1.0))
        };
        unlit_frame(&grid, model, w, h)
    };
    // The premise: on the wide frame some grid vertex lies right of the image, yet is not
    // clipped (no guard-band or near-plane bit), so it is snapped to fixed point.
    {
        use strata_raster::vertex::{ONE, ObjectTransform, Viewport, outcode, transform_vertex};
        let input = frame(MAX_SIDE, 1);
        let object = &input.objects[0];
        let t = ObjectTransform::new(input.view, object.model, input.projection);
        let vp = Viewport::new(input.width, input.height);
        let beyond = object.positions.iter().zip(object.normals).any(|(&p, &n)| {
            let (s, code, _) = transform_vertex(&t, &vp, p, n, false);
            code & outcode::CLIP == 0 && s.x > (MAX_SIDE as i32) * ONE
        });
        assert!(beyond, "no unclipped vertex beyond the image's right edge");
    }
    let mut raster = Rasterizer::default();
    for (w, h) in [(MAX_SIDE, 1), (1, MAX_SIDE)] {
        let mut out = FragmentVec::new();
        raster.prepare(&frame(w, h)).rasterize(&mut out);
        let mut per_pixel = vec![0u8; (w * h) as usize];
        for &(p, _) in out.fragments() {
            per_pixel[p as usize] += 1;
        }
        assert!(
            per_pixel.iter().all(|&n| n == 1),
            "{w}x{h}: every pixel exactly once"
        );
    }
    let wider = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        Rasterizer::default()
            .prepare(&frame(MAX_SIDE + 1, 1))
            .setup_stats()
    }));
    let message = wider.expect_err("a wider image is refused");
    let message = message
        .downcast_ref::<String>()
        .expect("a formatted message");
    assert!(message.contains("image sides are at most"), "{message}");
}

#[test]
fn strip_height_and_chunk_size_do_not_change_any_pixel() {
    // Same fragments, in the same (primitive) order, whatever the tiling: micro-triangle records
    // and binned triangles interleave by primitive, and chunks are walked in order.
    let scene = strata_scene::open_scene("spheres", &strata_scene::SearchPath::default())
        .expect("built-in");
    let mut scene = scene;
    (scene.width, scene.height) = (200, 120);
    let input = FrameInput::from_scene(&scene, 2);
    let render_with = |config: strata_raster::RasterConfig| {
        let mut raster = Rasterizer::new(config);
        let mut out = FragmentVec::new();
        raster.prepare(&input).rasterize(&mut out);
        out.per_pixel(input.pixel_count())
    };
    let reference = render_with(strata_raster::RasterConfig::default());
    assert!(reference.iter().map(Vec::len).sum::<usize>() > 10_000);
    for (strip_height, chunk_triangles) in [(1, 7), (8, 1000), (64, 1 << 20), (256, 3)] {
        let config = strata_raster::RasterConfig {
            strip_height,
            chunk_triangles,
        };
        assert!(
            render_with(config) == reference,
            "strip {strip_height}, chunk {chunk_triangles}"
        );
    }
}

#[test]
fn normal_fragments_carry_the_interpolated_normal_and_keep_depth_and_object() {
    // A plane tilted 40° about x (lit: every vertex normal is the plane's) beside an unlit one.
    let grid = jittered_grid(30, 1.0, 0.0, 0.3);
    let tilt = Mat4::from_translation(Vec3::new(-0.8, 0.0, -3.0))
        * Mat4::from_rotation_x(40f32.to_radians());
    let flat = Mat4::from_translation(Vec3::new(0.8, 0.0, -3.5));
    let cam = Cam::looking_down_z(64, 48);
    let objects = [
        (&grid, tilt, Shading::Headlight),
        (&grid, flat, Shading::Unlit),
    ];
    let shaded = render(&cam, &objects);
    let normals = render_as(&cam, &objects, FragmentOutput::PackedNormal);
    let want = (cam.view() * tilt).transform_vector3(Vec3::Z).normalize();
    let (mut lit, mut unlit) = (0, 0);
    for (s, n) in shaded.iter().zip(&normals) {
        assert_eq!(s.len(), n.len());
        for (a, b) in s.iter().zip(n) {
            assert_eq!((a.depth, a.object), (b.depth, b.object));
            let packed = PackedNormal::from_bits(b.color.to_bits());
            if b.object == ObjectId(0) {
                let u = Vec3::from(packed.unpack().expect("a lit fragment has a normal"));
                // Either side of the plane: headlight shading is two-sided.
                assert!(u.dot(want).abs() > 1.0 - 1e-7, "{u} vs {want}");
                lit += 1;
            } else {
                assert_eq!(packed, PackedNormal::NONE);
                unlit += 1;
            }
        }
    }
    assert!(lit > 100 && unlit > 100, "{lit} {unlit}");
}
