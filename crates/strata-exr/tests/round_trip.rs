//! Deep and flat images survive a write and a read unchanged, for every compression, sample
//! type, line order and window shape; the deep operations do what "Interpreting OpenEXR Deep
//! Pixels" says.

mod common;

use common::{assert_same_pixels, synthetic};
use proptest::prelude::*;
use strata_exr::{
    Attribute, Box2i, Channel, Column, Compression, DeepImage, ExrError, FlatImage, Limits,
    LineOrder, MAX_SPLIT_SAMPLES_PER_PIXEL, SampleType, WriteOptions, flatten, merge, read_deep,
    read_flat, read_info, sort, stats, write_deep, write_flat,
};

const DEEP_COMPRESSIONS: [Compression; 3] =
    [Compression::None, Compression::Rle, Compression::Zips];
const LINE_ORDERS: [LineOrder; 2] = [LineOrder::IncreasingY, LineOrder::DecreasingY];

fn windows() -> Vec<(&'static str, Box2i)> {
    vec![
        ("1x1", Box2i::from_origin(0, 0, 1, 1).unwrap()),
        ("odd 7x5", Box2i::from_origin(0, 0, 7, 5).unwrap()),
        ("offset 13x37", Box2i::from_origin(-4, 9, 13, 37).unwrap()),
        ("tall 3x40", Box2i::from_origin(100, -20, 3, 40).unwrap()),
    ]
}

fn options(compression: Compression, line_order: LineOrder) -> WriteOptions {
    WriteOptions {
        compression,
        line_order,
    }
}

/// The image read back, with the attributes the writer adds by default removed.
fn round_trip(image: &DeepImage, options: &WriteOptions) -> DeepImage {
    let bytes = write_deep(image, options).expect("writes");
    read_deep(&bytes, &Limits::default()).expect("reads back")
}

#[test]
fn deep_images_round_trip_in_every_compression_type_and_order() {
    for (what, window) in windows() {
        for colour in [SampleType::Half, SampleType::Float] {
            let image = synthetic(window, colour, 6, window.pixel_count());
            assert!(image.sample_count() > 0 || window.pixel_count() == 1);
            for compression in DEEP_COMPRESSIONS {
                for order in LINE_ORDERS {
                    let back = round_trip(&image, &options(compression, order));
                    assert_same_pixels(
                        &back,
                        &image,
                        &format!("{what} {colour:?} {compression:?} {order:?}"),
                    );
                }
            }
        }
    }
}

#[test]
fn an_image_without_samples_round_trips() {
    let window = Box2i::from_origin(3, 4, 9, 6).unwrap();
    let channels = vec![
        Channel::new("A", SampleType::Half),
        Channel::new("Z", SampleType::Float),
    ];
    let image = DeepImage::new(
        window,
        channels,
        vec![0; 55],
        vec![Column::F32(vec![]), Column::F32(vec![])],
    )
    .unwrap();
    for compression in DEEP_COMPRESSIONS {
        let back = round_trip(&image, &options(compression, LineOrder::IncreasingY));
        assert_same_pixels(&back, &image, &format!("{compression:?}"));
        assert_eq!(back.max_samples_per_pixel(), 0);
    }
}

#[test]
fn compression_shrinks_compressible_images() {
    let image = synthetic(
        Box2i::from_origin(0, 0, 64, 32).unwrap(),
        SampleType::Half,
        4,
        5,
    );
    let raw = write_deep(&image, &options(Compression::None, LineOrder::IncreasingY)).unwrap();
    for compression in [Compression::Rle, Compression::Zips] {
        let packed = write_deep(&image, &options(compression, LineOrder::IncreasingY)).unwrap();
        assert!(
            packed.len() < raw.len(),
            "{compression:?}: {} >= {}",
            packed.len(),
            raw.len()
        );
    }
}

#[test]
fn deep_zip_is_refused_with_advice() {
    let image = synthetic(
        Box2i::from_origin(0, 0, 4, 4).unwrap(),
        SampleType::Half,
        2,
        1,
    );
    let err = write_deep(&image, &options(Compression::Zip, LineOrder::IncreasingY)).unwrap_err();
    assert!(matches!(err, ExrError::Unsupported(_)), "{err:?}");
    assert!(err.to_string().contains("ZIPS"), "{err}");
}

#[test]
fn unknown_attributes_and_display_window_survive() {
    let mut image = synthetic(
        Box2i::from_origin(2, 3, 5, 4).unwrap(),
        SampleType::Float,
        3,
        2,
    );
    image.set_display_window(Box2i::from_origin(0, 0, 20, 10).unwrap());
    image.set_attribute(Attribute::string("owner", "a compositor"));
    image.set_attribute(Attribute::m44f("worldToCamera", [1.5; 16]));
    image.set_attribute(Attribute {
        name: "a.very.long.attribute.name.over.thirty.one.bytes".into(),
        type_name: "float".into(),
        value: 2.5f32.to_le_bytes().to_vec(),
    });
    let back = round_trip(&image, &WriteOptions::default());
    assert_same_pixels(&back, &image, "attributes");
    for a in image.attributes() {
        assert_eq!(back.attribute(&a.name), Some(a), "{}", a.name);
    }
    let info = read_info(&write_deep(&back, &WriteOptions::default()).unwrap()).unwrap();
    assert!(info.deep);
    assert_eq!(info.display_window, image.display_window());
}

#[test]
fn flat_images_round_trip_in_every_compression() {
    let w = Box2i::from_origin(-2, 5, 11, 19).unwrap();
    let pixels = w.pixel_count() as usize;
    let values = |k: usize| {
        (0..pixels)
            .map(|p| ((p * k) % 97) as f32 / 64.0)
            .collect::<Vec<_>>()
    };
    for sample_type in [SampleType::Half, SampleType::Float] {
        let image = FlatImage::new(
            w,
            vec![
                Channel::new("A", sample_type),
                Channel::new("R", sample_type),
                Channel::new("id", SampleType::Uint),
            ],
            vec![
                Column::F32(values(3)),
                Column::F32(values(5)),
                Column::U32((0..pixels as u32).map(|p| p * 7919).collect()),
            ],
        )
        .unwrap();
        for compression in Compression::ALL {
            for order in LINE_ORDERS {
                let bytes = write_flat(&image, &options(compression, order)).unwrap();
                let back = read_flat(&bytes, &Limits::default()).unwrap();
                assert_eq!(back.data_window(), image.data_window());
                assert_eq!(back.channels(), image.channels());
                for c in 0..3 {
                    assert_eq!(
                        back.column(c),
                        image.column(c),
                        "{sample_type:?} {compression:?} {order:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn readers_refuse_the_other_kind() {
    let deep = synthetic(
        Box2i::from_origin(0, 0, 3, 3).unwrap(),
        SampleType::Half,
        2,
        3,
    );
    let bytes = write_deep(&deep, &WriteOptions::default()).unwrap();
    let err = read_flat(&bytes, &Limits::default()).unwrap_err();
    assert!(
        matches!(
            err,
            ExrError::WrongKind {
                expected: "flat",
                found: "deep"
            }
        ),
        "{err:?}"
    );
    let flat = flatten(&deep).unwrap();
    let bytes = write_flat(&flat, &WriteOptions::default()).unwrap();
    let err = read_deep(&bytes, &Limits::default()).unwrap_err();
    assert!(
        matches!(
            err,
            ExrError::WrongKind {
                expected: "deep",
                found: "flat"
            }
        ),
        "{err:?}"
    );
}

/// A one-pixel image with samples `(Z, ZBack, A, R)` and channels A, R, Z, ZBack.
fn pixel(samples: &[(f32, f32, f32, f32)]) -> DeepImage {
    let col = |f: fn(&(f32, f32, f32, f32)) -> f32| Column::F32(samples.iter().map(f).collect());
    DeepImage::new(
        Box2i::from_origin(0, 0, 1, 1).unwrap(),
        vec![
            Channel::new("A", SampleType::Float),
            Channel::new("R", SampleType::Float),
            Channel::new("Z", SampleType::Float),
            Channel::new("ZBack", SampleType::Float),
        ],
        vec![0, samples.len() as u32],
        vec![col(|s| s.2), col(|s| s.3), col(|s| s.0), col(|s| s.1)],
    )
    .unwrap()
}

fn samples_of(image: &DeepImage) -> Vec<(f32, f32, f32, f32)> {
    let f = |c: &str| {
        image
            .column(image.channel_index(c).unwrap())
            .as_f32()
            .unwrap()
            .to_vec()
    };
    let (a, r, z, zb) = (f("A"), f("R"), f("Z"), f("ZBack"));
    (0..a.len()).map(|i| (z[i], zb[i], a[i], r[i])).collect()
}

#[test]
fn sort_orders_by_z_then_zback() {
    let image = pixel(&[
        (3.0, 3.0, 0.1, 0.1),
        (1.0, 2.0, 0.2, 0.2),
        (1.0, 1.5, 0.3, 0.3),
    ]);
    let z: Vec<_> = samples_of(&sort(&image))
        .iter()
        .map(|s| (s.0, s.1))
        .collect();
    assert_eq!(z, vec![(1.0, 1.5), (1.0, 2.0), (3.0, 3.0)]);
}

#[test]
fn flatten_composites_front_to_back() {
    // Stored front to back: 0.5 over 0.5 over opaque.
    let image = pixel(&[
        (1.0, 1.0, 0.5, 0.25),
        (2.0, 2.0, 0.5, 0.5),
        (3.0, 3.0, 1.0, 1.0),
        (4.0, 4.0, 1.0, 0.7),
    ]);
    let flat = flatten(&image).unwrap();
    assert_eq!(flat.value("A", 0), Some(1.0));
    // 0.25 + 0.5·0.5 + 0.25·1.0; the sample behind full opacity is ignored.
    assert_eq!(flat.value("R", 0), Some(0.75));
    let err = flatten(
        &DeepImage::new(
            Box2i::from_origin(0, 0, 1, 1).unwrap(),
            vec![Channel::new("Z", SampleType::Float)],
            vec![0, 0],
            vec![Column::F32(vec![])],
        )
        .unwrap(),
    )
    .unwrap_err();
    assert!(err.to_string().contains("no alpha channel"), "{err}");
}

#[test]
fn merge_splits_volumes_and_conserves_opacity() {
    // A volume from 1 to 3 with alpha 0.75, and a point sample at 2 in another image.
    let a = pixel(&[(1.0, 3.0, 0.75, 0.5)]);
    let b = pixel(&[(2.0, 2.0, 0.5, 0.1)]);
    let merged = samples_of(&merge(&[a, b]).unwrap());
    let depths: Vec<_> = merged.iter().map(|s| (s.0, s.1)).collect();
    // Ordered by Z alone, as released oiiotool does: at Z = 2 the volume's back half (from the
    // first image) stays ahead of the point sample (from the second).
    assert_eq!(depths, vec![(1.0, 2.0), (2.0, 3.0), (2.0, 2.0)]);
    // The two halves of the volume compose back to its alpha: (1 - a1)(1 - a2) = 1 - 0.75.
    let (a1, a2) = (merged[0].2, merged[1].2);
    assert!(((1.0 - a1) * (1.0 - a2) - 0.25).abs() < 1e-6, "{a1} {a2}");
    assert!(
        (a1 - 0.5).abs() < 1e-6,
        "equal halves of a homogeneous volume: {a1}"
    );
    // Colour is split in proportion to the alpha.
    assert!((merged[0].3 / merged[0].2 - 0.5 / 0.75).abs() < 1e-5);
}

#[test]
fn merge_combines_coincident_samples_and_culls_behind_opaque() {
    let a = pixel(&[(1.0, 1.0, 0.5, 0.5), (5.0, 5.0, 0.5, 0.2)]);
    let b = pixel(&[(1.0, 1.0, 0.5, 0.1), (3.0, 3.0, 1.0, 0.9)]);
    let merged = samples_of(&merge(&[a, b]).unwrap());
    // The two samples at Z = 1 become one with alpha 1 - 0.5·0.5; Z = 5 is behind the opaque 3.
    assert_eq!(merged.len(), 2, "{merged:?}");
    assert_eq!((merged[0].0, merged[0].2), (1.0, 0.75));
    assert!((merged[0].3 - 0.45).abs() < 1e-6, "{merged:?}");
    assert_eq!(merged[1].0, 3.0);
}

#[test]
fn merge_covers_the_union_of_windows_and_checks_channels() {
    let a = synthetic(
        Box2i::from_origin(0, 0, 4, 4).unwrap(),
        SampleType::Float,
        3,
        1,
    );
    let b = synthetic(
        Box2i::from_origin(2, 3, 5, 2).unwrap(),
        SampleType::Float,
        3,
        2,
    );
    let m = merge(&[a.clone(), b.clone()]).unwrap();
    assert_eq!(m.data_window(), Box2i::from_origin(0, 0, 7, 5).unwrap());
    // A pixel only `b` covers is b's pixel unchanged.
    let range = m.pixel_at(6, 4).unwrap();
    assert_eq!(range.len(), b.pixel_at(6, 4).unwrap().len());
    let c = pixel(&[(1.0, 1.0, 0.5, 0.5)]);
    let err = merge(&[a, c]).unwrap_err();
    assert!(matches!(err, ExrError::Mismatch(_)), "{err:?}");
    assert!(matches!(merge(&[]).unwrap_err(), ExrError::Mismatch(_)));
    let far = synthetic(
        Box2i::from_origin(1 << 30, 1 << 29, 2, 2).unwrap(),
        SampleType::Float,
        1,
        3,
    );
    let near = synthetic(
        Box2i::from_origin(-(1 << 30), 0, 2, 2).unwrap(),
        SampleType::Float,
        1,
        4,
    );
    let err = merge(&[near, far]).unwrap_err();
    assert!(err.to_string().contains("far apart"), "{err}");
}

#[test]
fn stats_count_samples() {
    let image = synthetic(
        Box2i::from_origin(5, 5, 9, 7).unwrap(),
        SampleType::Half,
        9,
        4,
    );
    let s = stats(&image);
    let counts: Vec<u32> = image.offsets().windows(2).map(|o| o[1] - o[0]).collect();
    assert_eq!(s.pixels, 63);
    assert_eq!(s.samples, counts.iter().map(|&c| u64::from(c)).sum::<u64>());
    assert_eq!(s.max_per_pixel, *counts.iter().max().unwrap());
    assert_eq!(
        s.empty_pixels,
        counts.iter().filter(|&&c| c == 0).count() as u64
    );
    assert_eq!(s.histogram.iter().sum::<u64>(), 63);
    let (x, y) = s.max_at;
    assert_eq!(image.pixel_at(x, y).unwrap().len() as u32, s.max_per_pixel);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn any_small_deep_image_round_trips(
        x in -50i32..50, y in -50i32..50, w in 1u32..12, h in 1u32..20,
        seed in any::<u64>(), max in 0u64..7, comp in 0usize..3, order in 0usize..2,
        half in any::<bool>(),
    ) {
        let window = Box2i::from_origin(x, y, w, h).unwrap();
        let colour = if half { SampleType::Half } else { SampleType::Float };
        let image = synthetic(window, colour, max, seed);
        let back = round_trip(&image, &options(DEEP_COMPRESSIONS[comp], LINE_ORDERS[order]));
        assert_same_pixels(&back, &image, "proptest");
    }
}

#[test]
fn read_info_lists_every_attribute_readably() {
    let mut image = synthetic(
        Box2i::from_origin(1, 2, 4, 3).unwrap(),
        SampleType::Half,
        2,
        5,
    );
    image.set_attribute(Attribute::double("strata.near", 0.25));
    image.set_attribute(Attribute::m44f(
        "worldToCamera",
        std::array::from_fn(|i| i as f32),
    ));
    let bytes = write_deep(&image, &WriteOptions::default()).unwrap();
    let info = read_info(&bytes).unwrap();
    let shown = |name: &str| {
        info.attributes
            .iter()
            .find(|a| a.name == name)
            .map(|a| a.to_string())
            .unwrap_or_else(|| panic!("no {name}"))
    };
    assert_eq!(shown("compression"), "zips");
    assert_eq!(shown("dataWindow"), "(1 2) - (4 4)");
    assert_eq!(shown("type"), "\"deepscanline\"");
    assert_eq!(
        shown("maxSamplesPerPixel"),
        image.max_samples_per_pixel().to_string()
    );
    assert_eq!(shown("lineOrder"), "increasing y");
    assert_eq!(shown("strata.near"), "0.25");
    assert!(
        shown("worldToCamera").starts_with("[0 1 2 3] [4 5 6 7]"),
        "{}",
        shown("worldToCamera")
    );
    assert_eq!(
        shown("channels"),
        "A (half), B (half), G (half), R (half), Z (float), ZBack (float), objectid (uint)"
    );
}

#[test]
fn flat_rgba_fills_missing_channels() {
    let w = Box2i::from_origin(0, 0, 2, 1).unwrap();
    let flat = FlatImage::new(
        w,
        vec![
            Channel::new("G", SampleType::Float),
            Channel::new("R", SampleType::Half),
        ],
        vec![Column::F32(vec![0.5, 0.25]), Column::F32(vec![1.0, 0.0])],
    )
    .unwrap();
    assert_eq!(
        flat.rgba(),
        vec![[1.0, 0.5, 0.0, 1.0], [0.0, 0.25, 0.0, 1.0]]
    );
    let rgba = [[0.1, 0.2, 0.3, 0.5], [0.0, 0.0, 0.0, 0.0]];
    assert_eq!(
        FlatImage::from_rgba(2, 1, &rgba, SampleType::Float)
            .unwrap()
            .rgba(),
        rgba.to_vec()
    );
}

#[test]
fn images_are_checked_on_construction() {
    let w = Box2i::from_origin(0, 0, 2, 1).unwrap();
    let a = || vec![Channel::new("A", SampleType::Half)];
    let cases: Vec<(Result<DeepImage, ExrError>, &str)> = vec![
        (
            DeepImage::new(w, vec![], vec![0, 0, 0], vec![]),
            "at least one channel",
        ),
        (
            DeepImage::new(w, a(), vec![0, 1], vec![Column::F32(vec![0.5])]),
            "offsets for 2 pixels",
        ),
        (
            DeepImage::new(w, a(), vec![0, 2, 1], vec![Column::F32(vec![0.5])]),
            "decrease",
        ),
        (
            DeepImage::new(w, a(), vec![0, 1, 2], vec![Column::F32(vec![0.5])]),
            "holds 1 values, expected 2",
        ),
        (
            DeepImage::new(w, a(), vec![0, 1, 1], vec![Column::U32(vec![1])]),
            "is half but its column holds integers",
        ),
        (
            DeepImage::new(
                w,
                vec![
                    Channel::new("Z", SampleType::Float),
                    Channel::new("A", SampleType::Half),
                ],
                vec![0, 0, 0],
                vec![Column::F32(vec![]), Column::F32(vec![])],
            ),
            "sorted by name",
        ),
    ];
    for (result, expected) in cases {
        let err = result.unwrap_err();
        assert!(
            matches!(err, ExrError::InvalidImage(_)) && err.to_string().contains(expected),
            "{err}"
        );
    }
    assert!(Box2i::from_origin(i32::MAX, 0, 2, 1).is_err());
    assert!(Box2i::from_origin(0, 0, 0, 1).is_err());
}

/// One pixel of an image with channels A, B, G, R, Z, ZBack (all FLOAT) from `(a, r, z, zback)`.
fn volumes(samples: &[(f32, f32, f32, f32)]) -> DeepImage {
    let window = Box2i::from_origin(0, 0, 1, 1).expect("window");
    let channels = ["A", "B", "G", "R", "Z", "ZBack"]
        .iter()
        .map(|n| Channel::new(*n, SampleType::Float))
        .collect();
    let col = |f: fn(&(f32, f32, f32, f32)) -> f32| Column::F32(samples.iter().map(f).collect());
    let columns = vec![
        col(|s| s.0),
        col(|_| 0.0),
        col(|_| 0.0),
        col(|s| s.1),
        col(|s| s.2),
        col(|s| s.3),
    ];
    DeepImage::new(window, channels, vec![0, samples.len() as u32], columns).expect("image")
}

#[test]
fn merge_puts_every_pixel_in_depth_order_even_with_one_input() {
    // Stored back to front: an opaque sample at Z 2, then one at Z 1.
    let unsorted = volumes(&[(1.0, 0.25, 2.0, 2.0), (1.0, 0.75, 1.0, 1.0)]);
    let merged = merge(std::slice::from_ref(&unsorted)).expect("merged");
    let z = merged.column(merged.channel_index("Z").expect("Z"));
    assert_eq!(z.as_f32().expect("float"), &[1.0, 2.0]);
    let flat = flatten(&merged).expect("flat");
    assert_eq!(flat.value("R", 0), Some(0.75), "the front sample shows");
}

#[test]
fn splitting_overlapping_volumes_is_bounded_per_pixel() {
    // n volumetric samples that all overlap, merged with the same shifted by a half: every
    // sample splits at about 2n boundaries.
    let n = 200usize;
    let a: Vec<(f32, f32, f32, f32)> = (0..n)
        .map(|i| (0.01, 0.01, i as f32, (n + i) as f32))
        .collect();
    let b: Vec<(f32, f32, f32, f32)> = a.iter().map(|s| (s.0, s.1, s.2 + 0.5, s.3 + 0.5)).collect();
    let err = merge(&[volumes(&a), volumes(&b)]).expect_err("too many pieces");
    let text = err.to_string();
    assert!(text.contains("pixel (0,0)"), "{text}");
    assert!(
        text.contains(&MAX_SPLIT_SAMPLES_PER_PIXEL.to_string()),
        "{text}"
    );
    // A smaller case still merges, into as many pieces as there are distinct ranges.
    let small: Vec<(f32, f32, f32, f32)> = a[..20]
        .iter()
        .map(|s| (s.0, s.1, s.2, s.2 + 20.0))
        .collect();
    let shifted: Vec<(f32, f32, f32, f32)> = small
        .iter()
        .map(|s| (s.0, s.1, s.2 + 0.5, s.3 + 0.5))
        .collect();
    let merged = merge(&[volumes(&small), volumes(&shifted)]).expect("merged");
    assert!(merged.sample_count() > 40, "{}", merged.sample_count());
}
