//! TFSS fed through its sinks directly, bypassing the rasterizer (as the linked list's tests do).

use super::*;
use crate::abuffer::linked_list::LinkedListABuffer;

fn frag(depth: f32, rgba: [u8; 4], object: u32) -> Fragment {
    Fragment {
        depth,
        color: Rgba8(rgba),
        object: ObjectId(object),
    }
}

fn layout(width: u32, height: u32, strip_height: u32) -> StripLayout {
    StripLayout {
        width,
        height,
        strip_height,
    }
}

/// Pushes `(pixel, fragment)` pairs through the sinks of `target`, then finishes every strip.
fn capture<T: CaptureTarget>(target: &mut T, layout: &StripLayout, frags: &[(u32, Fragment)]) {
    let mut sinks = target.sinks(layout);
    for &(p, f) in frags {
        sinks[p as usize / layout.pixels_per_strip()].push(p, f);
    }
    for s in &mut sinks {
        s.finish();
    }
}

fn tfss(l_num: u32, leading_zeros: bool, pool: PoolCapacity) -> Tfss {
    Tfss::new(&MethodOptions {
        l_num,
        leading_zeros,
        pool,
        ..MethodOptions::default()
    })
}

/// Ten fragments for pixel 5, two for pixel 13 and one for pixel 0 of a 4×4 frame, interleaved.
fn scene() -> Vec<(u32, Fragment)> {
    let mut v = Vec::new();
    for i in 0..10u32 {
        v.push((
            5,
            frag(1.0 - i as f32 / 16.0, [i as u8 * 25, 7, 200, 128], i),
        ));
        if i == 3 || i == 8 {
            v.push((13, frag(0.5, [0, i as u8, 0, 64], 100 + i)));
        }
        if i == 6 {
            v.push((0, frag(0.25, [1, 2, 3, 255], 99)));
        }
    }
    v
}

fn arrival(frags: &[(u32, Fragment)], p: u32) -> Vec<Fragment> {
    frags
        .iter()
        .filter(|(q, _)| *q == p)
        .map(|(_, f)| *f)
        .collect()
}

#[test]
fn sections_chain_through_the_nsa_table_in_arrival_order() {
    let frags = scene();
    let lay = layout(4, 4, 2);
    for leading_zeros in [false, true] {
        let mut t = tfss(3, leading_zeros, PoolCapacity::Fragments(300));
        t.clear(4, 4).unwrap();
        capture(&mut t, &lay, &frags);
        // Pixel 5: ten fragments in ⌈10/3⌉ = 4 sections filled 3, 3, 3, 1, linked in order.
        assert_eq!(t.section_fill(5), [3, 3, 3, 1], "lz {leading_zeros}");
        let chain = t.chain(5);
        assert_eq!(t.ssa[5], chain[0]);
        for w in chain.windows(2) {
            assert_eq!(t.nsa[w[0] as usize].load(Relaxed), w[1]);
        }
        assert_eq!(t.nsa[chain[3] as usize].load(Relaxed), NULL);
        assert_eq!(t.fragments(5), arrival(&frags, 5), "bit-exact, in order");
        assert_eq!(t.section_fill(13), [2]);
        assert_eq!(t.fragments(13), arrival(&frags, 13));
        assert_eq!(t.fragments(0), arrival(&frags, 0));
        assert!(t.chain(1).is_empty());
        assert_eq!(t.ssa[1], NULL);
        let m = t.memory();
        assert_eq!(m.sections_used, 4 + 1 + 1);
        assert_eq!(t.stored.load(Relaxed), 13);
        if !leading_zeros {
            // SSA 16·4, six sections of 3·12 bytes and their NSA entries, the counter.
            assert_eq!(m.used(), 64 + 6 * 36 + 6 * 4 + 4);
            assert_eq!(m.sections_allocated, 100);
            assert_eq!(m.allocated(), 64 + 100 * 36 + 100 * 4 + 4);
        }
    }
}

#[test]
fn one_fragment_sections_chain_every_fragment() {
    let frags = scene();
    let mut t = tfss(1, false, PoolCapacity::Fragments(64));
    t.clear(4, 4).unwrap();
    capture(&mut t, &layout(4, 4, 4), &frags);
    assert_eq!(t.chain(5).len(), 10);
    assert_eq!(t.fragments(5), arrival(&frags, 5));
    assert_eq!(t.memory().sections_used, 13);
}

#[test]
fn packed_sections_seal_when_a_record_does_not_fit() {
    // L_num 3, b = 2: area max(3·14, 32) = 42 bits. Dark fragments (len ≤ 2, 14-bit records)
    // fill three slots; a bright one (32 bits) seals a section that holds more than 10 bits.
    let dark = |d: f32| frag(d, [3, 0, 1, 77], 1);
    let bright = |d: f32| frag(d, [0, 255, 0, 200], 2);
    let seq = [
        dark(0.1),
        dark(0.2),
        bright(0.3), // 28 + 32 > 42: seals section 0, opens section 1
        dark(0.4),   // 32 + 14 > 42: seals section 1, opens section 2
        dark(0.5),
        dark(0.6),
        dark(0.7), // section 2 is full (3 slots): opens section 3
    ];
    let frags: Vec<_> = seq.iter().map(|&f| (2u32, f)).collect();
    let mut t = tfss(3, true, PoolCapacity::Fragments(300)).with_lz_budget(LzBudget::Bits(2));
    t.clear(4, 1).unwrap();
    capture(&mut t, &layout(4, 1, 1), &frags);
    assert_eq!(t.section_fill(2), [2, 1, 3, 1]);
    assert_eq!(t.fragments(2), seq);
    let reader = t.reader();
    let s1 = t.chain(2)[1];
    let code = |s: u32, i: u64| {
        LengthCode::from_bits(t.lengths.read(u64::from(s) * 12 + 4 * i, LENGTH_BITS))
    };
    assert_eq!(code(s1, 0), LengthCode::Stored(8));
    assert_eq!(code(s1, 1), LengthCode::Sealed);
    assert_eq!(code(t.chain(2)[0], 2), LengthCode::Sealed);
    assert_eq!(code(t.chain(2)[3], 1), LengthCode::Empty);
    assert_eq!(reader.chain_len(t.ssa[2]), 7);
    // The model packs the same lengths into the same sections.
    let lens = seq.iter().map(|f| {
        let [r, g, b, _] = f.color.0;
        lz::rgb_length([r, g, b]) as u8
    });
    assert_eq!(
        model::packed_sections_of(lens, 3, model::colour_area_bits(3, 2)),
        4
    );
    // Memory: four sections of 3·64 + 42 = 234 bits, 12 Length bits each, NSA, SSA, counter.
    let m = t.memory();
    assert_eq!(m.section_bits, 234);
    assert_eq!(m.t_buffer_used, (4 * 234u64).div_ceil(8));
    assert_eq!(m.length_used, 6);
    assert_eq!(m.used(), 16 + 117 + 16 + 6 + 4);
}

#[test]
fn resolve_and_deep_frame_equal_the_linked_list() {
    let frags = scene();
    let lay = layout(4, 4, 2);
    let mut ll = LinkedListABuffer::new(PoolCapacity::Fragments(100));
    ll.clear(4, 4).unwrap();
    capture(&mut ll, &lay, &frags);
    let want_image = ll.resolve([0.2, 0.4, 1.0], &mut PassTimings::new());
    let want_deep = ll.deep_frame().unwrap().unwrap();
    for (l_num, lz) in [(1, false), (2, false), (4, true), (7, true), (3, true)] {
        // Two strips reserve a block of 64 sections each.
        let mut t = tfss(l_num, lz, PoolCapacity::Fragments(128 * u64::from(l_num)));
        t.clear(4, 4).unwrap();
        capture(&mut t, &lay, &frags);
        assert_eq!(t.dropped.load(Relaxed), 0);
        assert_eq!(
            t.deep_frame().unwrap().unwrap(),
            want_deep,
            "L {l_num} lz {lz}"
        );
        assert_eq!(
            t.resolve([0.2, 0.4, 1.0], &mut PassTimings::new()),
            want_image
        );
        let s = t.depth_stats().unwrap();
        assert_eq!((s.fragments(), s.max_depth_complexity()), (13, 10));
    }
}

#[test]
fn exhausted_pool_drops_and_counts() {
    // One strip, a pool of 2 sections of 2: four fragments fit, the rest are dropped.
    let frags: Vec<_> = (0..9u32)
        .map(|i| (i % 2, frag(i as f32 / 10.0, [1, 1, 1, 128], i)))
        .collect();
    let mut t = tfss(2, false, PoolCapacity::Fragments(4));
    t.clear(2, 1).unwrap();
    capture(&mut t, &layout(2, 1, 1), &frags);
    assert_eq!(t.stored.load(Relaxed), 4);
    assert_eq!(t.dropped.load(Relaxed), 5);
    assert_eq!(t.section_fill(0), [2]);
    assert_eq!(t.section_fill(1), [2]);
    assert_eq!(t.deep_frame().unwrap().unwrap().fragment_count(), 4);
}

#[test]
fn clear_empties_every_chain_and_reuses_sections() {
    let frags = scene();
    let mut t = tfss(2, true, PoolCapacity::Fragments(200)).with_lz_budget(LzBudget::Bits(5));
    for _ in 0..2 {
        t.clear(4, 4).unwrap();
        assert!((0..16).all(|p| t.chain(p).is_empty()));
        capture(&mut t, &layout(4, 4, 2), &frags);
        // Reused words were zeroed when their block was reserved again.
        assert_eq!(t.fragments(5), arrival(&frags, 5));
    }
}

#[test]
fn l_num_is_clamped() {
    assert_eq!(tfss(0, false, PoolCapacity::Auto).l_num(), 1);
    assert_eq!(tfss(1000, false, PoolCapacity::Auto).l_num(), MAX_L_NUM);
    assert_eq!(tfss(2, false, PoolCapacity::Auto).name(), "tfss");
}
