//! A rectangle of pixels: the part of a frame a fast client touches (its objects' footprint), so
//! that exporting and compositing it costs what the footprint costs, not what the screen does.

/// The pixels `x .. x + width` × `y .. y + height` of a frame (row 0 on top).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct PixelRect {
    /// Left column.
    pub x: u32,
    /// Top row.
    pub y: u32,
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

impl PixelRect {
    /// The whole of a `width × height` frame.
    pub fn full(width: u32, height: u32) -> Self {
        PixelRect {
            x: 0,
            y: 0,
            width,
            height,
        }
    }

    /// The pixels of a `width × height` frame that clip-space points `[x, y, z, w]` project to,
    /// grown by `margin` pixels on every side (rounding, and the rasterizer's fill rule) and
    /// clipped to the frame; an empty rectangle for no points; `None` when a point lies at or
    /// behind the eye (`w ≤ 10⁻⁶` or NaN), whose projection is unbounded. Row 0 is on top.
    ///
    /// ```
    /// use strata_core::PixelRect;
    /// // The centre of a 10 × 10 frame, one pixel of margin.
    /// let r = PixelRect::around_clip_points([[0.0, 0.0, 0.5, 1.0]], 10, 10, 1.0);
    /// assert_eq!(r, Some(PixelRect { x: 4, y: 4, width: 2, height: 2 }));
    /// assert_eq!(PixelRect::around_clip_points([[0.0, 0.0, 0.5, -1.0]], 10, 10, 1.0), None);
    /// ```
    pub fn around_clip_points(
        points: impl IntoIterator<Item = [f32; 4]>,
        width: u32,
        height: u32,
        margin: f32,
    ) -> Option<PixelRect> {
        let (w, h) = (width as f32, height as f32);
        let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
        for [cx, cy, _, cw] in points {
            if cw.is_nan() || cw <= 1e-6 {
                return None;
            }
            let (x, y) = ((cx / cw + 1.0) * 0.5 * w, (1.0 - cy / cw) * 0.5 * h);
            lo = [lo[0].min(x), lo[1].min(y)];
            hi = [hi[0].max(x), hi[1].max(y)];
        }
        if !(lo[0] <= hi[0] && lo[1] <= hi[1]) {
            // No points (or NaN positions): nothing is drawn.
            return Some(PixelRect::default());
        }
        let clamp = |v: f32, max: f32| v.clamp(0.0, max) as u32;
        let (x0, y0) = (
            clamp((lo[0] - margin).floor(), w),
            clamp((lo[1] - margin).floor(), h),
        );
        let (x1, y1) = (
            clamp((hi[0] + margin).ceil(), w),
            clamp((hi[1] + margin).ceil(), h),
        );
        Some(PixelRect {
            x: x0,
            y: y0,
            width: x1 - x0,
            height: y1 - y0,
        })
    }

    /// Pixels in the rectangle.
    pub fn pixel_count(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Whether the rectangle lies inside a `width × height` frame.
    pub fn fits(&self, width: u32, height: u32) -> bool {
        u64::from(self.x) + u64::from(self.width) <= u64::from(width)
            && u64::from(self.y) + u64::from(self.height) <= u64::from(height)
    }

    /// The row-major index, in a frame `frame_width` wide, of the rectangle's pixel `q`
    /// (row-major within the rectangle).
    #[inline]
    pub fn frame_index(&self, q: usize, frame_width: u32) -> usize {
        let (i, j) = (q % self.width as usize, q / self.width as usize);
        (self.y as usize + j) * frame_width as usize + self.x as usize + i
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indices_map_into_the_frame() {
        let r = PixelRect {
            x: 2,
            y: 1,
            width: 3,
            height: 2,
        };
        let idx: Vec<usize> = (0..r.pixel_count()).map(|q| r.frame_index(q, 10)).collect();
        assert_eq!(idx, [12, 13, 14, 22, 23, 24]);
        assert!(r.fits(5, 3));
        assert!(!r.fits(4, 3));
        assert!(!r.fits(5, 2));
        assert_eq!(PixelRect::full(4, 3).pixel_count(), 12);
    }
}
