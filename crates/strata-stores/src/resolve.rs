//! The screen-space pass every resolve shares: all pixels in parallel, one rayon job per chunk of
//! pixels, depth statistics merged at the end.
//!
//! A method supplies what differs — how one pixel (or one chunk, for methods that batch their
//! memory accesses across pixels) becomes a colour and a fragment count — and gets the image and
//! the [`DepthStats`] of what it held.

use rayon::prelude::*;
use strata_core::{DepthStats, Rgb8Image};

/// Pixels per parallel job.
pub(crate) const PIXELS_PER_TASK: usize = 4096;

/// Resolves a `width` × `height` image chunk by chunk: `chunk(scratch, first, out, stats)` fills
/// `out` (RGB bytes of the pixels `first ..`) and records each pixel's fragment count in `stats`.
/// `init` makes one scratch value per job, reused for all its pixels.
pub(crate) fn resolve_chunks<S, I, C>(
    width: u32,
    height: u32,
    init: I,
    chunk: C,
) -> (Rgb8Image, DepthStats)
where
    I: Fn() -> S + Sync + Send,
    C: Fn(&mut S, usize, &mut [u8], &mut DepthStats) + Sync + Send,
{
    let mut image = Rgb8Image::filled(width, height, [0; 3]);
    let depth = image
        .as_bytes_mut()
        .par_chunks_mut(PIXELS_PER_TASK * 3)
        .with_max_len(1)
        .enumerate()
        .map_init(init, |scratch, (task, out)| {
            let mut stats = DepthStats::default();
            chunk(scratch, task * PIXELS_PER_TASK, out, &mut stats);
            stats
        })
        .reduce(DepthStats::default, |mut a, b| {
            a.merge(&b);
            a
        });
    (image, depth)
}

/// Resolves a `width` × `height` image pixel by pixel: `pixel(p)` returns row-major pixel `p`'s
/// colour and how many fragments it held.
pub(crate) fn resolve_pixels<P>(width: u32, height: u32, pixel: P) -> (Rgb8Image, DepthStats)
where
    P: Fn(usize) -> ([u8; 3], u32) + Sync + Send,
{
    resolve_chunks(
        width,
        height,
        || (),
        |_, first, out, stats| {
            for (i, px) in out.chunks_exact_mut(3).enumerate() {
                let (rgb, n) = pixel(first + i);
                stats.record(n);
                px.copy_from_slice(&rgb);
            }
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_pixel_once_and_statistics_merged() {
        // More pixels than one job, and a remainder chunk.
        let (w, h) = (100u32, 90u32);
        let (img, stats) = resolve_pixels(w, h, |p| ([p as u8, (p >> 8) as u8, 7], (p % 3) as u32));
        for p in [0usize, 4095, 4096, 8999] {
            let (x, y) = ((p % 100) as u32, (p / 100) as u32);
            assert_eq!(img.pixel(x, y), [p as u8, (p >> 8) as u8, 7]);
        }
        assert_eq!(stats.pixels(), 9000);
        assert_eq!(stats.histogram(), &[3000, 3000, 3000]);
    }
}
