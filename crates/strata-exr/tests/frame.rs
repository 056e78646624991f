//! strata's DeepFrames through deep OpenEXR files: bit-exact with float channels (and, for 8-bit
//! colour, with half channels too), on rendered built-in scenes and on arbitrary fragments.

mod common;

use common::{assert_same_frame, render};
use proptest::prelude::*;
use strata_core::{DeepFrame, Fragment, ObjectId, Rgba8};
use strata_exr::{
    Compression, DepthMapping, ExrError, FrameOptions, Limits, OBJECT_ID_CHANNEL, SampleType,
    WINDOW_DEPTH_CHANNEL, WriteOptions, deep_from_frame, frame_from_deep, read_deep, write_deep,
};

fn through_file(
    frame: &DeepFrame,
    depth: DepthMapping,
    options: &FrameOptions,
    compression: Compression,
) -> DeepFrame {
    let image = deep_from_frame(frame, depth, options).expect("converts");
    let bytes = write_deep(
        &image,
        &WriteOptions {
            compression,
            ..WriteOptions::default()
        },
    )
    .expect("writes");
    let back = read_deep(&bytes, &Limits::default()).expect("reads");
    frame_from_deep(&back, None).expect("converts back with the stored clip planes")
}

#[test]
fn rendered_frames_round_trip_bit_exactly() {
    for scene in ["spheres", "mixed"] {
        let r = render(scene, 128, 72);
        assert!(r.frame.fragment_count() > 1000, "{scene}: a real frame");
        for colour in [SampleType::Float, SampleType::Half] {
            for compression in [Compression::None, Compression::Rle, Compression::Zips] {
                let options = FrameOptions {
                    color: colour,
                    camera: Some(r.camera),
                    ..FrameOptions::default()
                };
                let back = through_file(&r.frame, r.depth, &options, compression);
                assert_same_frame(
                    &back,
                    &r.frame,
                    &format!("{scene} {colour:?} {compression:?}"),
                );
            }
        }
    }
}

/// Without the exact-depth channel, `Z` alone is inverted: exact for the depths these scenes
/// produce (the limitation near the near plane is covered below).
#[test]
fn z_alone_inverts_exactly_on_rendered_frames() {
    for scene in ["spheres", "mixed"] {
        let r = render(scene, 128, 72);
        let options = FrameOptions {
            exact_depth: false,
            z_back: true,
            ..FrameOptions::default()
        };
        let image = deep_from_frame(&r.frame, r.depth, &options).unwrap();
        assert!(image.channel_index(WINDOW_DEPTH_CHANNEL).is_none());
        assert!(image.channel_index("ZBack").is_some());
        let back = frame_from_deep(&image, None).unwrap();
        assert_same_frame(&back, &r.frame, scene);
    }
}

#[test]
fn z_is_eye_distance_and_depth_maps_monotonically() {
    let m = DepthMapping::new(0.5, 40.0).unwrap();
    assert!((f64::from(m.z_from_depth(0.0)) - 0.5).abs() < 1e-6);
    assert!((f64::from(m.z_from_depth(1.0)) - 40.0).abs() < 1e-4);
    // A point 2 units in front of the eye: z_ndc = (f + n - 2fn/Z) / (f - n).
    let d = ((40.5 - 40.0 / 2.0) / 39.5 + 1.0) / 2.0;
    assert!((f64::from(m.z_from_depth(d as f32)) - 2.0).abs() < 1e-5);
    let mut previous = m.z_from_depth(0.0);
    for i in 1..=1000 {
        let z = m.z_from_depth(i as f32 / 1000.0);
        assert!(z > previous, "Z must grow with depth");
        previous = z;
    }
    assert!(DepthMapping::new(1.0, 1.0).is_err());
    assert!(DepthMapping::new(0.0, 1.0).is_err());
}

/// Near the near plane many window depths share one `f32` Z, so `Z` alone cannot be exact
/// there; the `strata.depth` channel makes the round trip exact anyway.
#[test]
fn depths_that_share_a_z_come_back_exactly_through_the_depth_channel() {
    let m = DepthMapping::new(0.01, 100.0).unwrap();
    let (d1, d2) = (1e-9f32, 2e-9f32);
    assert_eq!(
        m.z_from_depth(d1),
        m.z_from_depth(d2),
        "the premise: one Z for both"
    );
    let frame = DeepFrame::from_pixel_lists(
        2,
        1,
        &[
            vec![Fragment {
                depth: d1,
                color: Rgba8([1, 2, 3, 255]),
                object: ObjectId(1),
            }],
            vec![Fragment {
                depth: d2,
                color: Rgba8([1, 2, 3, 255]),
                object: ObjectId(2),
            }],
        ],
    )
    .unwrap();
    let back = through_file(&frame, m, &FrameOptions::default(), Compression::Zips);
    assert_same_frame(&back, &frame, "tiny depths");
    let lossy = deep_from_frame(
        &frame,
        m,
        &FrameOptions {
            exact_depth: false,
            ..FrameOptions::default()
        },
    )
    .unwrap();
    let z_only = frame_from_deep(&lossy, None).unwrap();
    assert_ne!(
        z_only.depths(),
        frame.depths(),
        "Z alone cannot tell them apart"
    );
}

/// Every 8-bit colour and alpha pair survives premultiplication in half precision.
#[test]
fn half_colour_is_exact_for_every_8_bit_colour() {
    let m = DepthMapping::new(0.1, 10.0).unwrap();
    let lists: Vec<Vec<Fragment>> = (0..256u32)
        .map(|c| {
            (1..256u32)
                .map(|a| Fragment {
                    depth: a as f32 / 256.0,
                    color: Rgba8([c as u8, (255 - c) as u8, (c * 7) as u8, a as u8]),
                    object: ObjectId(a),
                })
                .collect()
        })
        .collect();
    let frame = DeepFrame::from_pixel_lists(16, 16, &lists).unwrap();
    let options = FrameOptions {
        color: SampleType::Half,
        ..FrameOptions::default()
    };
    assert_same_frame(
        &through_file(&frame, m, &options, Compression::Rle),
        &frame,
        "half",
    );
}

#[test]
fn zero_alpha_fragments_come_back_black() {
    let m = DepthMapping::new(0.1, 10.0).unwrap();
    let frame = DeepFrame::from_pixel_lists(
        1,
        1,
        &[vec![Fragment {
            depth: 0.5,
            color: Rgba8([200, 100, 50, 0]),
            object: ObjectId(3),
        }]],
    )
    .unwrap();
    let back = through_file(&frame, m, &FrameOptions::default(), Compression::None);
    assert_eq!(back.colors(), &[Rgba8([0, 0, 0, 0])]);
    assert_eq!(back.objects(), &[ObjectId(3)]);
}

#[test]
fn channels_and_attributes_are_as_documented() {
    let r = render("spheres", 32, 18);
    let options = FrameOptions {
        camera: Some(r.camera),
        ..FrameOptions::default()
    };
    let image = deep_from_frame(&r.frame, r.depth, &options).unwrap();
    let names: Vec<_> = image
        .channels()
        .iter()
        .map(|c| (c.name.as_str(), c.sample_type))
        .collect();
    assert_eq!(
        names,
        vec![
            ("A", SampleType::Float),
            ("B", SampleType::Float),
            ("G", SampleType::Float),
            ("R", SampleType::Float),
            ("Z", SampleType::Float),
            (OBJECT_ID_CHANNEL, SampleType::Uint),
            (WINDOW_DEPTH_CHANNEL, SampleType::Float),
        ]
    );
    assert_eq!(
        image.attribute("strata.near").and_then(|a| a.as_double()),
        Some(r.depth.near)
    );
    assert_eq!(
        image.attribute("strata.far").and_then(|a| a.as_double()),
        Some(r.depth.far)
    );
    assert_eq!(
        image
            .attribute("worldToCamera")
            .map(|a| a.type_name.as_str()),
        Some("m44f")
    );
    assert_eq!(
        image.attribute("worldToNDC").map(|a| a.value.len()),
        Some(64)
    );
}

#[test]
fn frame_from_deep_names_what_is_missing() {
    let r = render("spheres", 16, 9);
    let mut image = deep_from_frame(
        &r.frame,
        r.depth,
        &FrameOptions {
            exact_depth: false,
            ..FrameOptions::default()
        },
    )
    .unwrap();
    // Without the clip planes there is no way from Z to window depth.
    let stripped = strata_exr::DeepImage::new(
        image.data_window(),
        image.channels().to_vec(),
        image.offsets().to_vec(),
        image.columns().to_vec(),
    )
    .unwrap();
    let err = frame_from_deep(&stripped, None).unwrap_err();
    assert!(
        matches!(err, ExrError::Frame(_)) && err.to_string().contains("clip planes"),
        "{err}"
    );
    assert!(frame_from_deep(&stripped, Some(r.depth)).is_ok());
    image.set_attribute(strata_exr::Attribute::double("strata.near", -1.0));
    assert!(
        frame_from_deep(&image, None).is_err(),
        "invalid stored planes are not used"
    );
}

fn fragment() -> impl Strategy<Value = Fragment> {
    (0.0f32..=1.0, any::<[u8; 4]>(), any::<u32>()).prop_map(|(depth, mut c, object)| {
        c[3] = c[3].max(1);
        Fragment {
            depth: if depth == 0.0 { 0.0 } else { depth },
            color: Rgba8(c),
            object: ObjectId(object),
        }
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn any_frame_round_trips_bit_exactly(
        lists in prop::collection::vec(prop::collection::vec(fragment(), 0..5), 12),
        near in 0.001f64..1.0, span in 1.5f64..1000.0, half in any::<bool>(),
    ) {
        let frame = DeepFrame::from_pixel_lists(4, 3, &lists).unwrap();
        let m = DepthMapping::new(near, near * span).unwrap();
        let colour = if half { SampleType::Half } else { SampleType::Float };
        let options = FrameOptions { color: colour, ..FrameOptions::default() };
        assert_same_frame(&through_file(&frame, m, &options, Compression::Zips), &frame, "proptest");
    }

    /// `depth_from_z` returns a depth that maps back to the same Z for every depth.
    #[test]
    fn z_inversion_is_consistent(d in 0.0f32..=1.0, near in 0.001f64..1.0, span in 1.5f64..1000.0) {
        let m = DepthMapping::new(near, near * span).unwrap();
        let z = m.z_from_depth(d);
        prop_assert_eq!(m.z_from_depth(m.depth_from_z(z)).to_bits(), z.to_bits());
    }
}
