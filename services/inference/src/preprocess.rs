//! Frame -> model input tensor: resize (whole frame), colour order,
//! `(pixel * scale - mean) / std`, NCHW or NHWC.
//!
//! The resize is `fast_image_resize`'s (SIMD): `bilinear` is its
//! convolution with the bilinear (triangle) filter widened by the
//! downscale factor, as PIL's `resize(..., BILINEAR)` and OpenCV's
//! `INTER_AREA`-like antialiasing do, so a frame shrunk 2x averages every
//! source pixel instead of sampling two of each four (a plain 2-tap
//! bilinear differs from PIL in up to 2.3% of a downscaled frame's mask
//! pixels, issue 21 item 5); upscaling is plain bilinear. `nearest` picks
//! the source pixel under each destination pixel's centre. The resized
//! frame is 8-bit, as PIL's; normalisation follows in one pass.

use crate::model_config::{ColorOrder, InputSpec, Layout, Resize};
use farsight_interfaces::msg::{ImageHeader, ImageLayoutError, PixelEncoding};
use fast_image_resize as fir;

/// A frame the model input cannot be made from.
#[derive(Debug, thiserror::Error)]
pub enum PreprocessError {
    #[error(transparent)]
    Layout(#[from] ImageLayoutError),
    #[error("frames in {0} cannot be fed to a colour model (expected rgb8, bgr8 or rgba8)")]
    Encoding(PixelEncoding),
    #[error("resizing a {src_w}x{src_h} frame to the model's {dst_w}x{dst_h}: {reason}")]
    Resize {
        src_w: u32,
        src_h: u32,
        dst_w: u32,
        dst_h: u32,
        reason: String,
    },
}

/// Reusable preprocessing for one input spec (any frame size).
pub struct Preprocessor {
    spec: InputSpec,
    resizer: fir::Resizer,
    /// Rows of a strided frame, packed (only when the stride has padding).
    packed: Vec<u8>,
    /// The resized frame, 8-bit, in the frame's channel layout.
    resized: Vec<u8>,
    /// Per output channel (model order): factor and offset so value = p * a + b.
    affine: [(f32, f32); 3],
}

impl Preprocessor {
    pub fn new(spec: &InputSpec) -> Self {
        let affine =
            core::array::from_fn(|c| (spec.scale / spec.std[c], -spec.mean[c] / spec.std[c]));
        Self {
            spec: spec.clone(),
            resizer: fir::Resizer::new(),
            packed: Vec::new(),
            resized: Vec::new(),
            affine,
        }
    }

    /// Number of f32 values of the tensor.
    pub fn len(&self) -> usize {
        3 * self.spec.width as usize * self.spec.height as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Writes the tensor for `frame` into `out` (length [`Self::len`]).
    pub fn run(
        &mut self,
        header: &ImageHeader,
        frame: &[u8],
        out: &mut [f32],
    ) -> Result<(), PreprocessError> {
        header.validate(frame.len())?;
        let (pixel_type, bpp, swap) = match header.encoding {
            PixelEncoding::RGB8 => (fir::PixelType::U8x3, 3, false),
            PixelEncoding::BGR8 => (fir::PixelType::U8x3, 3, true),
            PixelEncoding::RGBA8 => (fir::PixelType::U8x4, 4, false),
            e => return Err(PreprocessError::Encoding(e)),
        };
        let (w, h) = (self.spec.width as usize, self.spec.height as usize);
        let resize_err = |reason: String| PreprocessError::Resize {
            src_w: header.width,
            src_h: header.height,
            dst_w: self.spec.width,
            dst_h: self.spec.height,
            reason,
        };
        // fast_image_resize reads packed rows; a padded stride is packed first.
        let row = header.width as usize * bpp;
        let stride = header.stride_bytes as usize;
        let src: &[u8] = if stride == row {
            &frame[..row * header.height as usize]
        } else {
            self.packed.clear();
            for r in frame.chunks(stride).take(header.height as usize) {
                self.packed.extend_from_slice(&r[..row]);
            }
            &self.packed
        };
        let src = fir::images::ImageRef::new(header.width, header.height, src, pixel_type)
            .map_err(|e| resize_err(e.to_string()))?;
        self.resized.resize(w * h * bpp, 0);
        let mut dst = fir::images::Image::from_slice_u8(
            self.spec.width,
            self.spec.height,
            &mut self.resized,
            pixel_type,
        )
        .map_err(|e| resize_err(e.to_string()))?;
        let alg = match self.spec.resize {
            Resize::Bilinear => fir::ResizeAlg::Convolution(fir::FilterType::Bilinear),
            Resize::Nearest => fir::ResizeAlg::Nearest,
        };
        self.resizer
            .resize(&src, &mut dst, &fir::ResizeOptions::new().resize_alg(alg))
            .map_err(|e| resize_err(e.to_string()))?;
        // Model channel c takes frame channel: RGB frame -> RGB model is identity.
        let want_bgr = self.spec.color == ColorOrder::Bgr;
        let chan: [usize; 3] = if want_bgr != swap {
            [2, 1, 0]
        } else {
            [0, 1, 2]
        };
        let plane = w * h;
        for (i, px) in self.resized.chunks_exact(bpp).enumerate() {
            for (c, &s) in chan.iter().enumerate() {
                let (k, o) = self.affine[c];
                let idx = match self.spec.layout {
                    Layout::Nchw => c * plane + i,
                    Layout::Nhwc => i * 3 + c,
                };
                out[idx] = px[s] as f32 * k + o;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::msg::Stamp;

    fn spec(layout: Layout, color: ColorOrder) -> InputSpec {
        InputSpec {
            name: "x".into(),
            layout,
            width: 2,
            height: 1,
            resize: Resize::Nearest,
            color,
            scale: 1.0 / 127.5,
            mean: [1.0; 3],
            std: [1.0; 3],
        }
    }

    #[test]
    fn nhwc_bgr_normalised_by_hand() {
        // 4x2 RGB frame to 2x1, nearest, centre-aligned: x = (d + 0.5) * 2 - 0.5
        // gives 0.5 -> column 1 and 2.5 -> column 3; y = 0.5 -> row 1.
        let h = ImageHeader::packed(Stamp::default(), 0, 4, 2, PixelEncoding::RGB8);
        let mut frame = vec![0u8; 24];
        frame[12 + 3..12 + 6].copy_from_slice(&[255, 0, 127]); // pixel (1, 1)
        frame[12 + 9..12 + 12].copy_from_slice(&[0, 255, 0]); // pixel (3, 1)
        let mut p = Preprocessor::new(&spec(Layout::Nhwc, ColorOrder::Bgr));
        let mut out = vec![0.0; p.len()];
        p.run(&h, &frame, &mut out).unwrap();
        let v = |x: f32| x / 127.5 - 1.0;
        let expect = [v(127.0), v(0.0), v(255.0), v(0.0), v(255.0), v(0.0)];
        for (o, e) in out.iter().zip(expect) {
            assert!((o - e).abs() < 1e-6, "{out:?}");
        }
    }

    #[test]
    fn nchw_bilinear_of_a_constant_image_is_constant() {
        let h = ImageHeader::packed(Stamp::default(), 0, 7, 5, PixelEncoding::RGB8);
        let frame = vec![51u8; 7 * 5 * 3];
        let mut s = spec(Layout::Nchw, ColorOrder::Rgb);
        s.resize = Resize::Bilinear;
        s.width = 3;
        s.height = 2;
        s.scale = 1.0 / 255.0;
        s.mean = [0.0; 3];
        let mut p = Preprocessor::new(&s);
        let mut out = vec![0.0; p.len()];
        p.run(&h, &frame, &mut out).unwrap();
        assert!(out.iter().all(|v| (v - 0.2).abs() < 1e-6));
        let bad = ImageHeader::packed(Stamp::default(), 0, 7, 5, PixelEncoding::MONO8);
        assert!(matches!(
            p.run(&bad, &frame[..35], &mut out),
            Err(PreprocessError::Encoding(_))
        ));
        assert!(matches!(
            p.run(&h, &frame[..10], &mut out),
            Err(PreprocessError::Layout(_))
        ));
    }

    #[test]
    fn bilinear_downscaling_averages_every_pixel_as_pils_antialiased_resize() {
        // Vertical stripes white, black, black, white, ...: 16 -> 4 columns.
        // A 2-tap bilinear samples source x = 4d + 1.5 (two black
        // columns) and gives black; the antialiased filter spans 8 columns
        // and gives their weighted mean: 128 inside, a little less at the
        // borders, where the filter is cut and renormalised as PIL does.
        let (sw, sh) = (16u32, 4u32);
        let frame: Vec<u8> = (0..sh * sw)
            .flat_map(|i| {
                let v = if matches!(i % sw % 4, 0 | 3) { 255 } else { 0 };
                [v; 3]
            })
            .collect();
        let h = ImageHeader::packed(Stamp::default(), 0, sw, sh, PixelEncoding::RGB8);
        let mut s = spec(Layout::Nchw, ColorOrder::Rgb);
        (s.width, s.height, s.scale, s.mean) = (4, 1, 1.0, [0.0; 3]);
        s.resize = Resize::Bilinear;
        let mut out = vec![0.0; 12];
        Preprocessor::new(&s).run(&h, &frame, &mut out).unwrap();
        for (i, v) in out.iter().enumerate() {
            let border = matches!(i % 4, 0 | 3);
            let tolerance = if border { 12.0 } else { 1.0 };
            assert!((*v - 128.0).abs() <= tolerance, "{out:?}");
        }
        // Nearest keeps a stripe's own value.
        s.resize = Resize::Nearest;
        Preprocessor::new(&s).run(&h, &frame, &mut out).unwrap();
        assert!(out.iter().all(|&v| v == 0.0 || v == 255.0), "{out:?}");

        // A padded stride gives what the packed frame gives.
        s.resize = Resize::Bilinear;
        let stride = sw as usize * 3 + 5;
        let mut padded = vec![9u8; stride * sh as usize];
        for r in 0..sh as usize {
            let row = sw as usize * 3;
            padded[r * stride..r * stride + row].copy_from_slice(&frame[r * row..(r + 1) * row]);
        }
        let mut hp = h;
        hp.stride_bytes = stride as u32;
        let mut from_padded = vec![0.0; 12];
        Preprocessor::new(&s)
            .run(&hp, &padded, &mut from_padded)
            .unwrap();
        Preprocessor::new(&s).run(&h, &frame, &mut out).unwrap();
        assert_eq!(from_padded, out);
    }
}
