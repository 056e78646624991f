//! The triple buffer between the clients: latest wins, never torn, never backwards; and the
//! transfer buffer's containment test.

use std::sync::Arc;

use strata_core::{DeepFrame, ObjectId};
use strata_mfr::{TransferBuffer, exchange};

/// A value that would show a torn read: both halves must always agree.
struct Pair {
    seq: u64,
    check: u64,
}

#[test]
fn the_reader_sees_whole_values_in_order_and_ends_on_the_last() {
    const N: u64 = 20_000;
    let (mut publisher, mut latest) = exchange::<Pair>();
    assert!(latest.latest().is_none(), "empty before the first publish");
    let writer = std::thread::spawn(move || {
        for seq in 0..N {
            let _ = publisher.publish(Arc::new(Pair {
                seq,
                check: seq.wrapping_mul(0x9E37_79B9_7F4A_7C15),
            }));
        }
    });
    let mut last = None::<u64>;
    let mut reads = 0u64;
    loop {
        let done = writer.is_finished();
        if let Some(v) = latest.latest() {
            assert_eq!(v.check, v.seq.wrapping_mul(0x9E37_79B9_7F4A_7C15), "torn");
            if let Some(l) = last {
                assert!(v.seq >= l, "went back from {l} to {}", v.seq);
            }
            last = Some(v.seq);
            reads += 1;
        }
        if done {
            break;
        }
    }
    writer.join().expect("the writer ran");
    // After the writer is done, the newest value is the last one: latest wins.
    let v = latest.latest().expect("published");
    assert_eq!(v.seq, N - 1);
    assert!(!latest.updated());
    assert!(reads > 0);
}

#[test]
fn a_value_is_read_until_a_newer_one_arrives() {
    let (mut publisher, mut latest) = exchange::<u64>();
    let _ = publisher.publish(Arc::new(1));
    let _ = publisher.publish(Arc::new(2));
    assert!(latest.updated());
    assert_eq!(latest.latest().map(|v| **v), Some(2), "1 was skipped");
    assert!(!latest.updated());
    assert_eq!(
        latest.latest().map(|v| **v),
        Some(2),
        "read again, same value"
    );
    let _ = publisher.publish(Arc::new(3));
    assert_eq!(latest.latest().map(|v| **v), Some(3));
}

#[test]
fn contained_means_rendered_at_the_same_version() {
    let buffer = TransferBuffer {
        sc_frame: 7,
        snapshot_id: 3,
        snapshot_t_ms: 30.0,
        view: strata_mfr::ViewPose {
            eye: glam::Vec3::Z,
            target: glam::Vec3::ZERO,
            up: glam::Vec3::Y,
        },
        rendered: vec![(ObjectId(0), 0), (ObjectId(2), 5)],
        excluded: vec![ObjectId(1)],
        frame: DeepFrame::empty(1, 1),
        image: strata_core::Rgb8Image::filled(1, 1, [0; 3]),
    };
    assert!(buffer.contains(ObjectId(0), 0));
    assert!(buffer.contains(ObjectId(2), 5));
    assert!(
        !buffer.contains(ObjectId(2), 6),
        "moved since the SC rendered it"
    );
    assert!(!buffer.contains(ObjectId(1), 0), "left out");
    assert!(!buffer.contains(ObjectId(9), 0), "unknown");
}
