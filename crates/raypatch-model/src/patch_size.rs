//! The image sizes a model renders: a Ray-Patch decoder with patch size k decodes whole k × k patches, so both
//! sides must be multiples of k, unless the model resizes its output (the official `rp_kwargs.h_out/w_out`).
//! The one home of that rule: the API (`raypatch::input`, which every surface calls) and the scene core's
//! target grid (`TargetViews::grid`) both ask it.

use crate::config::ModelConfig;

/// What sizes a model renders: its patch size `k` and whether any size goes (an output-resizing model).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PatchSize {
    /// Pixels per patch side (1 for a per-pixel decoder).
    pub k: usize,
    /// The model resizes its output to any size (it decodes the patch grid and resizes the result).
    pub any_size: bool,
}

impl PatchSize {
    pub fn of(config: &ModelConfig) -> PatchSize {
        PatchSize { k: config.patch_size(), any_size: config.resizes_output() }
    }

    /// Whether the model renders `width` x `height`.
    pub fn fits(self, width: usize, height: usize) -> bool {
        self.any_size || (width.is_multiple_of(self.k) && height.is_multiple_of(self.k))
    }

    /// The sizes nearest to `width` x `height` that the model renders (none with a side of 0), nearest first (by
    /// the sum of the two sides' differences; of two as near, the smaller first); the size itself when it does.
    pub fn nearest(self, width: usize, height: usize) -> Vec<(usize, usize)> {
        if self.fits(width, height) {
            return vec![(width, height)];
        }
        let k = self.k.max(1);
        let near = |v: usize| {
            let below = v / k * k;
            if below == v {
                vec![v]
            } else {
                [below, below + k].into_iter().filter(|&s| s > 0).collect()
            }
        };
        let mut sizes: Vec<(usize, usize)> =
            near(width).into_iter().flat_map(|w| near(height).into_iter().map(move |h| (w, h))).collect();
        sizes.sort_by_key(|&(w, h)| w.abs_diff(width) + h.abs_diff(height));
        sizes
    }

    /// Why the model cannot render `width` x `height`, naming the nearest sizes it renders; `Ok` when it can.
    pub fn check(self, width: usize, height: usize) -> Result<(), String> {
        if self.fits(width, height) {
            return Ok(());
        }
        let nearest: Vec<String> = self.nearest(width, height).iter().map(|(w, h)| format!("{w}x{h}")).collect();
        Err(format!(
            "target size {width}x{height} (width x height) is not divisible by the model's patch size k={}; nearest \
             valid sizes: {}",
            self.k,
            nearest.join(", ")
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_k_does_not_divide_name_the_nearest_that_it_does() {
        let k4 = PatchSize { k: 4, any_size: false };
        assert_eq!(k4.check(80, 60), Ok(()));
        let error = k4.check(81, 60).unwrap_err();
        assert!(error.ends_with("k=4; nearest valid sizes: 80x60, 84x60"), "{error}");
        assert_eq!(k4.nearest(50, 30), vec![(48, 28), (48, 32), (52, 28), (52, 32)]);
        assert_eq!(k4.nearest(2, 3), vec![(4, 4)], "no side of 0");
        let resizing = PatchSize { k: 8, any_size: true };
        assert_eq!(resizing.check(60, 80), Ok(()));
    }
}
