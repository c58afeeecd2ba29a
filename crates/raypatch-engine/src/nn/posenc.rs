//! The official `PositionalEncoding`: per coordinate, sin then cos of the coordinate times each multiplier.

use raypatch_model::Octaves;

use crate::graph::{Graph, Tensor};
use crate::kernels::posenc::{fourier_encode, multipliers, FourierArgs};

pub struct FourierEncoding {
    pub path: String,
    pub octaves: Octaves,
    /// The multipliers in f32, as torch computes them.
    pub multipliers: Vec<f32>,
}

impl FourierEncoding {
    pub fn new(path: &str, octaves: &Octaves) -> FourierEncoding {
        FourierEncoding {
            path: path.to_string(),
            octaves: octaves.clone(),
            multipliers: multipliers(octaves.count, octaves.start, octaves.end),
        }
    }

    /// Columns of the encoding of a 3-vector.
    pub fn width(&self) -> usize {
        6 * self.multipliers.len()
    }

    /// Encodes `coords` `[R, 3]` into columns `col..col + width()` of `out`, output row r reading coordinate
    /// row `(first_row + r) / repeat` (a camera position broadcast over its view's `repeat` rays).
    pub fn forward_into(
        &self,
        g: &mut Graph,
        coords: Tensor,
        repeat: usize,
        first_row: usize,
        out: Tensor,
        col: usize,
    ) {
        let label = g.label(&self.path);
        let args =
            FourierArgs { coords: coords.view, repeat, first_row, multipliers: &self.multipliers, out: out.view, col };
        fourier_encode(&mut g.b, &label, args);
    }
}
