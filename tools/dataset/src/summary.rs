//! Example pictures of a dataset: the labels over their image, so a person
//! can see at a glance whether the projection and the rules are right.

use crate::lrn::LrnLabel;
use farsight_costmap_fusion::labels::SwathLabel;

/// Upscale factor of the example pictures.
const SCALE: usize = 4;

/// Colours of FITAM's classes, slowest first, and of "no label".
const CLASS_RGB: [[u8; 3]; 3] = [[200, 40, 40], [230, 200, 40], [40, 190, 60]];
const NONE_RGB: [u8; 3] = [60, 60, 60];

/// An RGB picture `(width, height, pixels)`: the image upscaled, LRN's
/// labels over it (red = 0, green = hotspot, untouched = unlabelled), and
/// under it one column of boxes per FITAM slice, nearest radial bin at the
/// bottom, coloured by class (red slow, yellow medium, green fast, grey
/// none) and darker for a lower weight.
pub fn example(
    image: &[u8],
    w: usize,
    h: usize,
    lrn: Option<&LrnLabel>,
    fitam: &[Option<SwathLabel>],
    slices: usize,
    radial: usize,
) -> (usize, usize, Vec<u8>) {
    let (ow, box_h) = (w * SCALE, 12);
    let oh = h * SCALE + radial * box_h;
    let mut out = vec![0u8; ow * oh * 3];
    for y in 0..h * SCALE {
        for x in 0..ow {
            let i = (y / SCALE) * w + x / SCALE;
            let mut px = [image[3 * i], image[3 * i + 1], image[3 * i + 2]];
            if let Some(l) = lrn.filter(|l| l.labelled[i]) {
                let a = l.value[i] as f32 / 255.0;
                let tint = [255.0 * (1.0 - a), 255.0 * a, 0.0];
                for c in 0..3 {
                    px[c] = (0.45 * px[c] as f32 + 0.55 * tint[c]) as u8;
                }
            }
            out[3 * (y * ow + x)..][..3].copy_from_slice(&px);
        }
    }
    for s in 0..slices {
        for r in 0..radial {
            let (rgb, weight) = match fitam.get(s * radial + r).copied().flatten() {
                Some(l) => (CLASS_RGB[l.class_id.min(2)], l.observed_fraction),
                None => (NONE_RGB, 1.0),
            };
            let y0 = h * SCALE + (radial - 1 - r) * box_h;
            let (x0, x1) = (s * ow / slices, (s + 1) * ow / slices);
            for y in y0 + 1..y0 + box_h - 1 {
                for x in x0 + 1..x1.saturating_sub(1) {
                    for c in 0..3 {
                        out[3 * (y * ow + x) + c] = (rgb[c] as f32 * (0.3 + 0.7 * weight)) as u8;
                    }
                }
            }
        }
    }
    (ow, oh, out)
}
