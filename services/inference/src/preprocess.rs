//! Frame -> model input tensor: resize (whole frame, bilinear or nearest),
//! colour order, `(pixel * scale - mean) / std`, NCHW or NHWC, in one pass over
//! the output with precomputed resampling taps.

use crate::model_config::{ColorOrder, InputSpec, Layout, Resize};
use farsight_interfaces::msg::{ImageHeader, ImageLayoutError, PixelEncoding};

/// A frame the model input cannot be made from.
#[derive(Debug, thiserror::Error)]
pub enum PreprocessError {
    #[error(transparent)]
    Layout(#[from] ImageLayoutError),
    #[error("frames in {0} cannot be fed to a colour model (expected rgb8, bgr8 or rgba8)")]
    Encoding(PixelEncoding),
}

/// One resampling tap along an axis: two source indices and the weight of the second.
#[derive(Debug, Clone, Copy)]
struct Tap {
    i0: usize,
    i1: usize,
    w1: f32,
}

fn taps(src: usize, dst: usize, resize: Resize) -> Vec<Tap> {
    let scale = src as f32 / dst as f32;
    (0..dst)
        .map(|d| {
            // Pixel centres align: source coordinate of destination centre d + 0.5.
            let x = ((d as f32 + 0.5) * scale - 0.5).clamp(0.0, (src - 1) as f32);
            match resize {
                Resize::Nearest => {
                    let i = (x + 0.5).floor().min((src - 1) as f32) as usize;
                    Tap {
                        i0: i,
                        i1: i,
                        w1: 0.0,
                    }
                }
                Resize::Bilinear => {
                    let i0 = x.floor() as usize;
                    let i1 = (i0 + 1).min(src - 1);
                    Tap {
                        i0,
                        i1,
                        w1: x - i0 as f32,
                    }
                }
            }
        })
        .collect()
}

/// Reusable preprocessing for one input spec and one frame size.
pub struct Preprocessor {
    spec: InputSpec,
    src: (u32, u32),
    xt: Vec<Tap>,
    yt: Vec<Tap>,
    /// Per output channel (model order): factor and offset so value = p * a + b.
    affine: [(f32, f32); 3],
}

impl Preprocessor {
    pub fn new(spec: &InputSpec, src_width: u32, src_height: u32) -> Self {
        let affine =
            core::array::from_fn(|c| (spec.scale / spec.std[c], -spec.mean[c] / spec.std[c]));
        Self {
            spec: spec.clone(),
            src: (src_width, src_height),
            xt: taps(src_width.max(1) as usize, spec.width as usize, spec.resize),
            yt: taps(
                src_height.max(1) as usize,
                spec.height as usize,
                spec.resize,
            ),
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
        let (bpp, swap) = match header.encoding {
            PixelEncoding::RGB8 => (3, false),
            PixelEncoding::BGR8 => (3, true),
            PixelEncoding::RGBA8 => (4, false),
            e => return Err(PreprocessError::Encoding(e)),
        };
        if (header.width, header.height) != self.src {
            *self = Self::new(&self.spec, header.width, header.height);
        }
        // Model channel c takes frame channel: RGB frame -> RGB model is identity.
        let want_bgr = self.spec.color == ColorOrder::Bgr;
        let chan: [usize; 3] = if want_bgr != swap {
            [2, 1, 0]
        } else {
            [0, 1, 2]
        };
        let (w, h) = (self.spec.width as usize, self.spec.height as usize);
        let stride = header.stride_bytes as usize;
        let plane = w * h;
        for (y, ty) in self.yt.iter().enumerate() {
            let r0 = &frame[ty.i0 * stride..];
            let r1 = &frame[ty.i1 * stride..];
            let wy1 = ty.w1;
            let wy0 = 1.0 - wy1;
            for (x, tx) in self.xt.iter().enumerate() {
                let (a, b) = (tx.i0 * bpp, tx.i1 * bpp);
                let wx1 = tx.w1;
                let wx0 = 1.0 - wx1;
                for (c, &s) in chan.iter().enumerate() {
                    let top = r0[a + s] as f32 * wx0 + r0[b + s] as f32 * wx1;
                    let bot = r1[a + s] as f32 * wx0 + r1[b + s] as f32 * wx1;
                    let p = top * wy0 + bot * wy1;
                    let (k, o) = self.affine[c];
                    let idx = match self.spec.layout {
                        Layout::Nchw => c * plane + y * w + x,
                        Layout::Nhwc => (y * w + x) * 3 + c,
                    };
                    out[idx] = p * k + o;
                }
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
        let mut p = Preprocessor::new(&spec(Layout::Nhwc, ColorOrder::Bgr), 4, 2);
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
        let mut p = Preprocessor::new(&s, 7, 5);
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
}
