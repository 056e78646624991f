//! The DeepFrame-aware layout: per-pixel counts, then each fragment column replaced by what a
//! predictor from already-sent neighbours got wrong, laid out for a byte-oriented compressor.
//!
//! A DeepFrame is not an arbitrary byte string: most pixels hold 0 or a few fragments and their
//! neighbours hold about as many; each run is sorted; a surface seen at layer `k` of one pixel is
//! usually seen at layer `k` of the next pixel too, and there its window depth is an affine function
//! of the screen position (planar triangles) and its shaded colour varies slowly; the object id
//! hardly ever changes. The thesis layout hides all of that from LZ4. This layout exposes it.
//!
//! # Neighbourhood
//!
//! Fragments are visited in DeepFrame order (pixels row-major, each run front to back). Fragment
//! `k` of pixel `(x, y)` is predicted from fragment `k` (the same *layer*) of its left `L = (x-1, y)`,
//! upper `U = (x, y-1)` and upper-left `UL = (x-1, y-1)` neighbours where those pixels hold more than
//! `k` fragments, else from the previous fragment `P` of its own run (`k > 0`), else from the first
//! fragment of the last non-empty run visited (`F`), else from zero. All of these precede it, so the
//! decoder, which visits in the same order, has them.
//!
//! # Sections (in this order)
//!
//! | tag | bytes before compression | what |
//! | --- | --- | --- |
//! | `counts` (16) | `w·h` varints | fragments per pixel, unsigned LEB128 (one byte below 128) |
//! | `depth` (17) | `4·n`: four planes of `n` bytes | zigzag(depth bits − prediction), byte `j` of every residual in plane `j` (little end first) |
//! | `color` (18) | `4·n`: four planes of `n` bytes | (channel − prediction) mod 256, plane 0 red … plane 3 alpha |
//! | `object` (19) | varints | object id XOR prediction, zero-run coded |
//!
//! **Depth** is predicted on its IEEE bits (a non-negative `f32` orders like its bits, and bits
//! make the arithmetic exact): `L + U − UL` (the plane through the three neighbours, exact for a
//! planar surface up to the rasteriser's rounding) when all three exist, else `L`, `U`, `P`, `F`,
//! 0. Arithmetic is modulo 2^32 and the residual is read as an `i32` before zigzag coding, so any
//! bits round-trip. The four bytes of a residual go to four planes, so the compressor sees the
//! mostly-zero high bytes as long runs and the noisy low bytes together.
//!
//! **Colour** is predicted per channel with the median edge detector of LOCO-I / JPEG-LS
//! (`min(L, U)` if `UL >= max(L, U)`, `max(L, U)` if `UL <= min(L, U)`, else `L + U − UL`) when all
//! three exist, else `L`, `U`, `P`, `F`, 0. A constant alpha becomes a plane of zeros.
//!
//! **Object ids** are predicted by `L`, `U`, `P`, `F`, 0 (no arithmetic: ids are labels) and the
//! residual is `id XOR prediction`, mostly 0. The stream is `run, value, run, value, …, run` as
//! varints: `run` zero residuals, then one residual `value` (non-zero), …, ending with the run that
//! reaches `n` fragments.
//!
//! Why each transform is there, measured on 1280×720 frames, is in `docs/wire-format.md`.
//!
//! # Decoding
//!
//! The counts come first: they must add up to the header's fragment count before any fragment
//! column is allocated. The decoder then replays the predictors; every stream must be consumed
//! exactly; the result goes through `DeepFrame::from_parts`, which re-checks sortedness and depth
//! range, so a well-formed message with nonsense residuals is an error, not a frame.

use rayon::prelude::*;
use strata_core::{DeepFrame, ObjectId, Rgba8};

use crate::bytes::{Reader, put_varint, unzigzag, zigzag};
use crate::codec::SectionTag;
use crate::error::WireError;

/// The run of a neighbouring pixel: where it starts and how many fragments it holds (0 when the
/// neighbour is outside the frame).
#[derive(Clone, Copy)]
struct Nb {
    start: usize,
    len: usize,
}

const NONE: Nb = Nb { start: 0, len: 0 };

/// The left, upper and upper-left runs of pixel `p`.
#[inline]
fn neighbours(offsets: &[u32], width: usize, p: usize) -> (Nb, Nb, Nb) {
    let run = |q: usize| Nb {
        start: offsets[q] as usize,
        len: (offsets[q + 1] - offsets[q]) as usize,
    };
    let x = p % width;
    let l = if x > 0 { run(p - 1) } else { NONE };
    let (u, ul) = if p >= width {
        (
            run(p - width),
            if x > 0 { run(p - width - 1) } else { NONE },
        )
    } else {
        (NONE, NONE)
    };
    (l, u, ul)
}

/// Which neighbours fragment `k` of a pixel can be predicted from.
#[derive(Clone, Copy)]
enum Source {
    /// `L`, `U` and `UL` all hold layer `k`: indices of the three.
    Plane(usize, usize, usize),
    /// One earlier fragment: `L`, `U` or `P`.
    One(usize),
    /// The first fragment of the last non-empty run (or nothing yet).
    Last,
}

#[inline]
fn source(k: usize, start: usize, l: Nb, u: Nb, ul: Nb) -> Source {
    let (hl, hu) = (k < l.len, k < u.len);
    if hl && hu && k < ul.len {
        Source::Plane(l.start + k, u.start + k, ul.start + k)
    } else if hl {
        Source::One(l.start + k)
    } else if hu {
        Source::One(u.start + k)
    } else if k > 0 {
        Source::One(start + k - 1)
    } else {
        Source::Last
    }
}

#[inline]
fn predict_depth(bits: &[u32], s: Source, last: u32) -> u32 {
    match s {
        Source::Plane(l, u, ul) => bits[l].wrapping_add(bits[u]).wrapping_sub(bits[ul]),
        Source::One(i) => bits[i],
        Source::Last => last,
    }
}

/// LOCO-I's median edge detector.
#[inline]
fn med(a: u8, b: u8, c: u8) -> u8 {
    let (lo, hi) = if a < b { (a, b) } else { (b, a) };
    if c >= hi {
        lo
    } else if c <= lo {
        hi
    } else {
        // lo < c < hi, so a + b - c lies in (lo, hi).
        (i16::from(a) + i16::from(b) - i16::from(c)) as u8
    }
}

#[inline]
fn predict_color(colors: &[[u8; 4]], s: Source, last: [u8; 4]) -> [u8; 4] {
    match s {
        Source::Plane(l, u, ul) => {
            let (a, b, c) = (colors[l], colors[u], colors[ul]);
            [
                med(a[0], b[0], c[0]),
                med(a[1], b[1], c[1]),
                med(a[2], b[2], c[2]),
                med(a[3], b[3], c[3]),
            ]
        }
        Source::One(i) => colors[i],
        Source::Last => last,
    }
}

#[inline]
fn predict_object(objects: &[u32], s: Source, last: u32) -> u32 {
    match s {
        // Ids are labels: the left neighbour, not an average.
        Source::Plane(l, _, _) | Source::One(l) => objects[l],
        Source::Last => last,
    }
}

/// Zero-run coder of the object residuals.
struct ZeroRuns {
    out: Vec<u8>,
    run: u32,
}

impl ZeroRuns {
    #[inline]
    fn push(&mut self, r: u32) {
        if r == 0 {
            self.run += 1;
        } else {
            put_varint(&mut self.out, self.run);
            put_varint(&mut self.out, r);
            self.run = 0;
        }
    }

    fn finish(mut self) -> Vec<u8> {
        put_varint(&mut self.out, self.run);
        self.out
    }
}

/// Rows of pixels one encoding task predicts.
const BAND_ROWS: usize = 16;

/// The four uncompressed sections, in wire order.
pub(crate) fn encode(frame: &DeepFrame) -> Vec<(SectionTag, Vec<u8>)> {
    encode_in_bands(frame, BAND_ROWS)
}

/// One band's outputs: its fragments' residuals, plane by plane, and its object residuals.
struct BandOut<'a> {
    depth: [&'a mut [u8]; 4],
    color: [&'a mut [u8]; 4],
    object: &'a mut [u32],
}

/// [`encode`] with the prediction cut into tasks of `band_rows` rows, run in parallel.
///
/// A residual depends only on the *original* values of the fragment's neighbours, which the
/// encoder has for the whole frame, so bands can be predicted in any order: each task writes
/// its own fragments' residuals (a contiguous range of every plane) and starts with the "last
/// non-empty run" of the pixels before it, found beforehand. The output is the same bytes for
/// any band height and thread count (tested). The object residuals are zero-run coded after,
/// in one pass; the counts' varints are one pass too.
fn encode_in_bands(frame: &DeepFrame, band_rows: usize) -> Vec<(SectionTag, Vec<u8>)> {
    let offsets = frame.offsets();
    let width = frame.width() as usize;
    let pixels = offsets.len() - 1;
    let n = frame.fragment_count();

    let mut counts = Vec::with_capacity(pixels + pixels / 8);
    for c in frame.counts() {
        put_varint(&mut counts, c);
    }

    let band_pixels = band_rows.max(1).saturating_mul(width).max(1);
    let bands: Vec<std::ops::Range<usize>> = (0..pixels)
        .step_by(band_pixels)
        .map(|p0| p0..(p0 + band_pixels).min(pixels))
        .collect();
    // The first fragment of the last non-empty run before each band (`None`: there is none).
    let mut last_before = Vec::with_capacity(bands.len());
    let mut last: Option<usize> = None;
    for band in &bands {
        last_before.push(last);
        if let Some(q) = band.clone().rev().find(|&q| offsets[q + 1] > offsets[q]) {
            last = Some(offsets[q] as usize);
        }
    }

    let mut depth = vec![0u8; 4 * n];
    let mut color = vec![0u8; 4 * n];
    let mut object = vec![0u32; n];
    {
        let (mut d, mut c, mut o) = (
            planes(&mut depth, n),
            planes(&mut color, n),
            &mut object[..],
        );
        let mut tasks = Vec::with_capacity(bands.len());
        for (band, last) in bands.iter().zip(&last_before) {
            let len = (offsets[band.end] - offsets[band.start]) as usize;
            let out = BandOut {
                depth: d.each_mut().map(|plane| take_front(plane, len)),
                color: c.each_mut().map(|plane| take_front(plane, len)),
                object: take_front(&mut o, len),
            };
            tasks.push((band.clone(), *last, out));
        }
        tasks
            .into_par_iter()
            .for_each(|(band, last, mut out)| predict_band(frame, band, last, &mut out));
    }
    let mut zero_runs = ZeroRuns {
        out: Vec::new(),
        run: 0,
    };
    for &r in &object {
        zero_runs.push(r);
    }
    vec![
        (SectionTag::Counts, counts),
        (SectionTag::Depth, depth),
        (SectionTag::Color, color),
        (SectionTag::Object, zero_runs.finish()),
    ]
}

/// The four planes of `n` bytes of `v`.
fn planes(v: &mut [u8], n: usize) -> [&mut [u8]; 4] {
    let (a, rest) = v.split_at_mut(n);
    let (b, rest) = rest.split_at_mut(n);
    let (c, d) = rest.split_at_mut(n);
    [a, b, c, d]
}

/// The first `len` items of `slice`, which keeps the rest.
fn take_front<'a, T>(slice: &mut &'a mut [T], len: usize) -> &'a mut [T] {
    let (head, tail) = std::mem::take(slice).split_at_mut(len);
    *slice = tail;
    head
}

/// The residuals of the fragments of the pixels in `band` into `out` (indexed from the band's
/// first fragment); `last` is the first fragment of the last non-empty run before the band.
fn predict_band(
    frame: &DeepFrame,
    band: std::ops::Range<usize>,
    last: Option<usize>,
    out: &mut BandOut<'_>,
) {
    let offsets = frame.offsets();
    let width = frame.width() as usize;
    // Plain views of the columns: bits for depth, byte arrays for colour, u32 for ids.
    let bits: &[f32] = frame.depths();
    let colors: &[Rgba8] = frame.colors();
    let objects: &[ObjectId] = frame.objects();
    let bit = |i: usize| bits[i].to_bits();
    let (mut last_depth, mut last_color, mut last_object) = match last {
        Some(i) => (bit(i), colors[i].0, objects[i].0),
        None => (0u32, [0u8; 4], 0u32),
    };
    let base = offsets[band.start] as usize;
    for p in band {
        let start = offsets[p] as usize;
        let len = offsets[p + 1] as usize - start;
        if len == 0 {
            continue;
        }
        let (l, u, ul) = neighbours(offsets, width, p);
        for k in 0..len {
            let i = start + k;
            let j = i - base;
            let s = source(k, start, l, u, ul);
            let predicted = match s {
                Source::Plane(l, u, ul) => bit(l).wrapping_add(bit(u)).wrapping_sub(bit(ul)),
                Source::One(q) => bit(q),
                Source::Last => last_depth,
            };
            let r = zigzag(bit(i).wrapping_sub(predicted) as i32);
            let [b0, b1, b2, b3] = r.to_le_bytes();
            out.depth[0][j] = b0;
            out.depth[1][j] = b1;
            out.depth[2][j] = b2;
            out.depth[3][j] = b3;
            let pc = predict_color_of(colors, s, last_color);
            let c = colors[i].0;
            for (plane, (value, guess)) in out.color.iter_mut().zip(c.into_iter().zip(pc)) {
                plane[j] = value.wrapping_sub(guess);
            }
            let po = match s {
                Source::Plane(l, _, _) | Source::One(l) => objects[l].0,
                Source::Last => last_object,
            };
            out.object[j] = objects[i].0 ^ po;
        }
        (last_depth, last_color, last_object) = (bit(start), colors[start].0, objects[start].0);
    }
}

/// [`predict_color`] over the frame's own colour column.
#[inline]
fn predict_color_of(colors: &[Rgba8], s: Source, last: [u8; 4]) -> [u8; 4] {
    match s {
        Source::Plane(l, u, ul) => {
            let (a, b, c) = (colors[l].0, colors[u].0, colors[ul].0);
            [
                med(a[0], b[0], c[0]),
                med(a[1], b[1], c[1]),
                med(a[2], b[2], c[2]),
                med(a[3], b[3], c[3]),
            ]
        }
        Source::One(i) => colors[i].0,
        Source::Last => last,
    }
}

/// Rebuilds the frame from the four decompressed sections (`section_offsets`: where each payload
/// starts in the message, for errors). Lengths were checked against
/// [`SectionTag::decoded_range`] before decompressing.
pub(crate) fn decode(
    width: u32,
    height: u32,
    fragments: u32,
    sections: &[Vec<u8>],
    section_offsets: &[u64],
) -> Result<DeepFrame, WireError> {
    let [counts, depth, color, object] = sections else {
        return Err(WireError::section(
            "counts",
            section_offsets.first().copied().unwrap_or(0),
            format!("the deep layout has 4 sections, found {}", sections.len()),
        ));
    };
    let at = |i: usize| section_offsets.get(i).copied().unwrap_or(0);
    let pixels = width as usize * height as usize;
    let n = fragments as usize;
    let w = width as usize;

    // Counts first: nothing per fragment is allocated before they add up.
    let mut reader = Reader::new(counts, 0);
    let mut offsets = Vec::with_capacity(pixels + 1);
    offsets.push(0u32);
    let mut total: u64 = 0;
    for p in 0..pixels {
        let c = reader
            .varint("count")
            .map_err(|e| WireError::section("counts", at(0), format!("pixel {p}: {e}")))?;
        total += u64::from(c);
        if total > n as u64 {
            return Err(WireError::section(
                "counts",
                at(0),
                format!(
                    "the counts up to pixel {p} add up to {total}, more than the {n} fragments the header announces"
                ),
            ));
        }
        offsets.push(total as u32);
    }
    if total != n as u64 {
        return Err(WireError::section(
            "counts",
            at(0),
            format!("the counts add up to {total}, the header announces {n} fragments"),
        ));
    }
    if reader.remaining() != 0 {
        return Err(WireError::section(
            "counts",
            at(0),
            format!(
                "{} bytes left after the {pixels} counts",
                reader.remaining()
            ),
        ));
    }
    if depth.len() != 4 * n || color.len() != 4 * n {
        return Err(WireError::section(
            "depth",
            at(1),
            format!(
                "depth and colour need {} bytes each, found {} and {}",
                4 * n,
                depth.len(),
                color.len()
            ),
        ));
    }

    let (d0, rest) = depth.split_at(n);
    let (d1, rest) = rest.split_at(n);
    let (d2, d3) = rest.split_at(n);
    let (c0, rest) = color.split_at(n);
    let (c1, rest) = rest.split_at(n);
    let (c2, c3) = rest.split_at(n);
    let mut bits = vec![0u32; n];
    let mut colors = vec![[0u8; 4]; n];
    let mut objects = vec![0u32; n];
    let mut ids = Reader::new(object, 0);
    let object_error =
        |e: WireError| WireError::section("object", at(3), format!("zero-run stream: {e}"));
    // Zero residuals left in the current run; `None` once the final run has been read.
    let mut zeros_left: u64 = u64::from(ids.varint("run").map_err(object_error)?);
    let (mut last_depth, mut last_color, mut last_object) = (0u32, [0u8; 4], 0u32);
    let mut i = 0usize;
    for p in 0..pixels {
        let start = offsets[p] as usize;
        let len = offsets[p + 1] as usize - start;
        if len == 0 {
            continue;
        }
        let (l, u, ul) = neighbours(&offsets, w, p);
        for k in 0..len {
            debug_assert_eq!(i, start + k);
            let s = source(k, start, l, u, ul);
            let r = u32::from_le_bytes([d0[i], d1[i], d2[i], d3[i]]);
            bits[i] = predict_depth(&bits, s, last_depth).wrapping_add(unzigzag(r) as u32);
            let pc = predict_color(&colors, s, last_color);
            colors[i] = [
                pc[0].wrapping_add(c0[i]),
                pc[1].wrapping_add(c1[i]),
                pc[2].wrapping_add(c2[i]),
                pc[3].wrapping_add(c3[i]),
            ];
            let residual = if zeros_left > 0 {
                zeros_left -= 1;
                0
            } else {
                let v = ids.varint("value").map_err(object_error)?;
                zeros_left = u64::from(ids.varint("run").map_err(object_error)?);
                v
            };
            objects[i] = predict_object(&objects, s, last_object) ^ residual;
            i += 1;
        }
        (last_depth, last_color, last_object) = (bits[start], colors[start], objects[start]);
    }
    if zeros_left != 0 || ids.remaining() != 0 {
        return Err(WireError::section(
            "object",
            at(3),
            format!(
                "the zero-run stream covers more than the {n} fragments ({zeros_left} zeros and {} bytes left)",
                ids.remaining()
            ),
        ));
    }
    let depth = bits.into_iter().map(f32::from_bits).collect();
    let color = colors.into_iter().map(Rgba8).collect();
    let object = objects.into_iter().map(ObjectId).collect();
    Ok(DeepFrame::from_parts(
        width, height, offsets, depth, color, object,
    )?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn med_is_the_loco_i_predictor() {
        assert_eq!(med(10, 20, 25), 10); // UL above both: the smaller
        assert_eq!(med(10, 20, 5), 20); // UL below both: the larger
        assert_eq!(med(10, 20, 12), 18); // in between: the plane
        assert_eq!(med(255, 255, 0), 255);
        assert_eq!(med(0, 255, 254), 1);
    }

    /// A frame with empty rows, empty pixels inside bands, deep runs and several objects.
    fn patchy_frame(width: u32, height: u32) -> DeepFrame {
        let lists: Vec<Vec<strata_core::Fragment>> = (0..width * height)
            .map(|p| {
                let (x, y) = (p % width, p / width);
                let count = if y % 5 == 2 || (x + y) % 7 == 0 {
                    0
                } else {
                    (x * 3 + y) % 4
                };
                (0..count)
                    .map(|k| strata_core::Fragment {
                        depth: 0.1 + 0.2 * k as f32 + 0.001 * x as f32 + 0.0007 * y as f32,
                        color: Rgba8([(x * 7) as u8, (y * 5) as u8, (k * 60) as u8, 128]),
                        object: ObjectId(1 + (x / 9 + k) % 3),
                    })
                    .collect()
            })
            .collect();
        DeepFrame::from_pixel_lists(width, height, &lists).expect("a valid frame")
    }

    #[test]
    fn any_band_height_and_thread_count_give_the_same_bytes() {
        let frame = patchy_frame(37, 29);
        let one = encode_in_bands(&frame, 1000);
        for rows in [1, 2, 3, 16, 29, 30] {
            assert_eq!(encode_in_bands(&frame, rows), one, "{rows} rows a band");
        }
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a pool");
            assert_eq!(
                pool.install(|| encode_in_bands(&frame, 1)),
                one,
                "{threads} threads"
            );
        }
        // And it decodes to the frame.
        let sections: Vec<Vec<u8>> = one.into_iter().map(|(_, bytes)| bytes).collect();
        let decoded =
            decode(37, 29, frame.fragment_count() as u32, &sections, &[0; 4]).expect("decodes");
        assert_eq!(decoded, frame);
    }

    #[test]
    fn zero_runs_end_with_the_final_run() {
        let mut z = ZeroRuns {
            out: Vec::new(),
            run: 0,
        };
        for r in [0, 0, 5, 0, 300, 0, 0, 0] {
            z.push(r);
        }
        assert_eq!(z.finish(), vec![2, 5, 1, 0xac, 0x02, 3]);
    }
}
