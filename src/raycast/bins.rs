//! Items binned by the cells of a 2D grid their boxes reach: the image's tiles a projected
//! facet may cover ([`super::raster`]), the cells across the Sun's direction a sun-facing
//! facet may shadow ([`super::sun_grid`]). Compressed rows: each cell's items in item order.

/// Item indices by cell, row-major.
pub struct Bins {
    cols: usize,
    /// `items[starts[c]..starts[c + 1]]` are cell `c`'s.
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl Bins {
    /// A grid of `cols x rows` cells and, per item, the inclusive ranges of cell columns and
    /// rows its box reaches (`[[x0, x1], [y0, y1]]`, inside the grid).
    pub fn new([cols, rows]: [usize; 2], spans: &[[[usize; 2]; 2]]) -> Bins {
        let cells = |&[[x0, x1], [y0, y1]]: &[[usize; 2]; 2]| {
            (y0..=y1).flat_map(move |y| (x0..=x1).map(move |x| y * cols + x))
        };
        let mut starts = vec![0u32; cols * rows + 1];
        for span in spans {
            for c in cells(span) {
                starts[c + 1] += 1;
            }
        }
        for c in 1..starts.len() {
            starts[c] += starts[c - 1];
        }
        let mut next = starts.clone();
        let mut items = vec![0u32; starts[cols * rows] as usize];
        for (k, span) in spans.iter().enumerate() {
            for c in cells(span) {
                items[next[c] as usize] = k as u32;
                next[c] += 1;
            }
        }
        Bins {
            cols,
            starts,
            items,
        }
    }

    /// The items of cell `(x, y)`.
    #[inline]
    pub fn cell(&self, x: usize, y: usize) -> &[u32] {
        let c = y * self.cols + x;
        &self.items[self.starts[c] as usize..self.starts[c + 1] as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_cell_lists_the_items_whose_spans_reach_it_in_order() {
        let b = Bins::new(
            [3, 2],
            &[[[0, 1], [0, 0]], [[1, 2], [0, 1]], [[0, 0], [1, 1]]],
        );
        assert_eq!(b.cell(0, 0), &[0]);
        assert_eq!(b.cell(1, 0), &[0, 1]);
        assert_eq!(b.cell(2, 0), &[1]);
        assert_eq!(b.cell(0, 1), &[2]);
        assert_eq!(b.cell(1, 1), &[1]);
        assert_eq!(b.cell(2, 1), &[1]);
    }
}
