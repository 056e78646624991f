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
