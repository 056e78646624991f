//! Shared test helpers: synthetic deep images, rendered DeepFrames and comparisons.

#![allow(
    dead_code,
    unreachable_pub,
    reason = "each test binary uses a different subset"
)]

use strata_core::DeepFrame;
use strata_exr::{Box2i, CameraMatrices, Channel, Column, DeepImage, DepthMapping, SampleType};
use strata_raster::{FrameInput, Rasterizer};
use strata_scene::{SearchPath, open_scene};
use strata_stores::{MethodOptions, create, render_frame};

/// A small deterministic generator (xorshift64*).
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    pub fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// A deep image over `window` with channels A, B, G, R (of `colour` type), Z (float), ZBack
/// (float) and objectid (uint); 0 to `max_samples` samples per pixel (about a third empty),
/// sorted by Z, values exactly representable in half so any colour type round-trips exactly.
pub fn synthetic(window: Box2i, color: SampleType, max_samples: u64, seed: u64) -> DeepImage {
    let mut rng = Rng(seed.wrapping_mul(2).wrapping_add(1));
    let pixels = window.pixel_count() as usize;
    let mut offsets = vec![0u32];
    for p in 0..pixels {
        let n = if rng.below(3) == 0 {
            0
        } else {
            rng.below(max_samples + 1) as u32
        };
        offsets.push(offsets[p] + n);
    }
    let total = offsets[pixels] as usize;
    let mut cols: Vec<Vec<f32>> = (0..6).map(|_| Vec::with_capacity(total)).collect();
    let mut ids = Vec::with_capacity(total);
    for p in 0..pixels {
        let mut z = 0.5f32;
        for _ in offsets[p]..offsets[p + 1] {
            let a = (1 + rng.below(64)) as f32 / 64.0;
            cols[0].push(a);
            for col in &mut cols[1..4] {
                col.push(a * rng.below(33) as f32 / 32.0);
            }
            z += (1 + rng.below(100)) as f32 / 8.0;
            cols[4].push(z);
            cols[5].push(z + rng.below(3) as f32 / 4.0);
            ids.push(rng.next() as u32);
        }
    }
    let channels = vec![
        Channel::new("A", color),
        Channel::new("B", color),
        Channel::new("G", color),
        Channel::new("R", color),
        Channel::new("Z", SampleType::Float),
        Channel::new("ZBack", SampleType::Float),
        Channel::new("objectid", SampleType::Uint),
    ];
    let mut columns: Vec<Column> = cols.into_iter().map(Column::F32).collect();
    columns.push(Column::U32(ids));
    DeepImage::new(window, channels, offsets, columns).expect("a valid synthetic image")
}

/// The pixels of two images are the same (windows, channels, offsets, values as bits).
#[track_caller]
pub fn assert_same_pixels(a: &DeepImage, b: &DeepImage, what: &str) {
    assert_eq!(a.data_window(), b.data_window(), "{what}: data window");
    assert_eq!(
        a.display_window(),
        b.display_window(),
        "{what}: display window"
    );
    assert_eq!(a.channels(), b.channels(), "{what}: channels");
    assert_eq!(a.offsets(), b.offsets(), "{what}: offsets");
    for (c, (x, y)) in a.columns().iter().zip(b.columns()).enumerate() {
        let bits = |col: &Column| match col {
            Column::F32(v) => v.iter().map(|f| f.to_bits()).collect::<Vec<_>>(),
            Column::U32(v) => v.clone(),
        };
        let (x, y) = (bits(x), bits(y));
        let first = x.iter().zip(&y).position(|(p, q)| p != q);
        assert!(
            x.len() == y.len() && first.is_none(),
            "{what}: channel {} differs at sample {first:?}",
            a.channels()[c].name
        );
    }
}

/// A rendered built-in scene: its DeepFrame, clip planes and camera matrices.
pub struct Rendered {
    pub frame: DeepFrame,
    pub depth: DepthMapping,
    pub camera: CameraMatrices,
}

/// Built-in scene `name` at `width` × `height`, rendered with the linked-list A-buffer.
pub fn render(name: &str, width: u32, height: u32) -> Rendered {
    let mut scene =
        open_scene(name, &SearchPath::default()).unwrap_or_else(|e| panic!("{name}: {e}"));
    (scene.width, scene.height) = (width, height);
    let input = FrameInput::from_scene(&scene, 0);
    let mut abuffer = create("abuffer", &MethodOptions::default()).expect("abuffer exists");
    let mut raster = Rasterizer::default();
    render_frame(abuffer.as_mut(), &mut raster, &input, scene.background)
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let frame = abuffer
        .deep_frame()
        .expect("the A-buffer exports a DeepFrame")
        .expect("a valid DeepFrame");
    let depth = DepthMapping::new(f64::from(scene.camera.near), f64::from(scene.camera.far))
        .expect("the scene's clip planes are valid");
    let camera = CameraMatrices {
        view: input.view.to_cols_array(),
        projection: input.projection.to_cols_array(),
    };
    Rendered {
        frame,
        depth,
        camera,
    }
}

/// The same DeepFrame: offsets, depths as bits, colours and objects.
#[track_caller]
pub fn assert_same_frame(a: &DeepFrame, b: &DeepFrame, what: &str) {
    assert_eq!(
        (a.width(), a.height()),
        (b.width(), b.height()),
        "{what}: size"
    );
    assert_eq!(a.offsets(), b.offsets(), "{what}: offsets");
    let bits = |f: &DeepFrame| f.depths().iter().map(|d| d.to_bits()).collect::<Vec<_>>();
    let (da, db) = (bits(a), bits(b));
    let first = da.iter().zip(&db).position(|(x, y)| x != y);
    assert!(
        first.is_none(),
        "{what}: depth differs at fragment {first:?}"
    );
    let first = a.colors().iter().zip(b.colors()).position(|(x, y)| x != y);
    assert!(
        first.is_none(),
        "{what}: colour differs at fragment {first:?}"
    );
    assert_eq!(a.objects(), b.objects(), "{what}: objects");
}
