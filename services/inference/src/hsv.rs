//! POVNav's colour-based navigability (section 4.2, "plain colour thresholds"):
//! a pixel is navigable when its HSV colour falls in any configured range.
//! Light enough for a microcontroller, and a baseline that needs no model.
//!
//! ```toml
//! [[hsv.ranges]]            # a grey-brown dirt road
//! hue_deg = [20.0, 50.0]    # hue_deg = [350.0, 10.0] wraps through red
//! saturation = [0.0, 0.35]
//! value = [0.35, 1.0]
//! ```

use farsight_interfaces::msg::{ImageHeader, PixelEncoding};
use farsight_stage::{ConfigError, Range, Ranges, Validate};
use serde::{Deserialize, Serialize};

/// One accepted colour range.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HsvRange {
    /// Hue interval in degrees; `min > max` wraps through 0 (reds).
    pub hue_deg: [f32; 2],
    /// Saturation interval in [0, 1].
    pub saturation: [f32; 2],
    /// Value (brightness) interval in [0, 1].
    pub value: [f32; 2],
}

impl Validate for HsvRange {
    fn ranges(&self, r: &mut Ranges) {
        r.each(
            "hue_deg",
            &self.hue_deg,
            Range::between(0.0, 360.0).unit("deg"),
        )
        .each("saturation", &self.saturation, Range::between(0.0, 1.0))
        .each("value", &self.value, Range::between(0.0, 1.0));
    }

    fn check_rules(&self) -> Result<(), ConfigError> {
        for (key, [lo, hi]) in [("saturation", self.saturation), ("value", self.value)] {
            ConfigError::check(
                lo <= hi,
                key,
                format!("[{lo}, {hi}]"),
                "[min, max] with min <= max",
            )?;
        }
        Ok(())
    }
}

impl HsvRange {
    fn contains(&self, h: f32, s: f32, v: f32) -> bool {
        let [h0, h1] = self.hue_deg;
        let hue_ok = if h0 <= h1 {
            (h0..=h1).contains(&h)
        } else {
            h >= h0 || h <= h1
        };
        hue_ok
            && (self.saturation[0]..=self.saturation[1]).contains(&s)
            && (self.value[0]..=self.value[1]).contains(&v)
    }
}

/// Hue (degrees), saturation and value of an RGB pixel.
pub fn rgb_to_hsv(r: u8, g: u8, b: u8) -> (f32, f32, f32) {
    let (r, g, b) = (r as f32 / 255.0, g as f32 / 255.0, b as f32 / 255.0);
    let max = r.max(g).max(b);
    let min = r.min(g).min(b);
    let d = max - min;
    let h = if d == 0.0 {
        0.0
    } else if max == r {
        60.0 * ((g - b) / d).rem_euclid(6.0)
    } else if max == g {
        60.0 * ((b - r) / d + 2.0)
    } else {
        60.0 * ((r - g) / d + 4.0)
    };
    let s = if max == 0.0 { 0.0 } else { d / max };
    (h, s, max)
}

/// The navigability image (255 = navigable) of an RGB8/BGR8 frame.
pub fn navigability(
    header: &ImageHeader,
    frame: &[u8],
    ranges: &[HsvRange],
) -> Result<Vec<u8>, crate::preprocess::PreprocessError> {
    header.validate(frame.len())?;
    let swap = match header.encoding {
        PixelEncoding::RGB8 => false,
        PixelEncoding::BGR8 => true,
        e => return Err(crate::preprocess::PreprocessError::Encoding(e)),
    };
    let (w, h, stride) = (
        header.width as usize,
        header.height as usize,
        header.stride_bytes as usize,
    );
    let mut out = Vec::with_capacity(w * h);
    for y in 0..h {
        for px in frame[y * stride..y * stride + w * 3].chunks_exact(3) {
            let (r, b) = if swap { (px[2], px[0]) } else { (px[0], px[2]) };
            let (hh, s, v) = rgb_to_hsv(r, px[1], b);
            out.push(if ranges.iter().any(|rg| rg.contains(hh, s, v)) {
                255
            } else {
                0
            });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use farsight_interfaces::msg::Stamp;

    #[test]
    fn hsv_of_primaries() {
        assert_eq!(rgb_to_hsv(255, 0, 0), (0.0, 1.0, 1.0));
        assert_eq!(rgb_to_hsv(0, 255, 0), (120.0, 1.0, 1.0));
        assert_eq!(rgb_to_hsv(0, 0, 255), (240.0, 1.0, 1.0));
        let (h, s, v) = rgb_to_hsv(128, 128, 128);
        assert_eq!((h, s), (0.0, 0.0));
        assert!((v - 128.0 / 255.0).abs() < 1e-6);
    }

    #[test]
    fn ranges_with_hue_wrap_and_bgr_frames() {
        let red = HsvRange {
            hue_deg: [340.0, 20.0],
            saturation: [0.5, 1.0],
            value: [0.2, 1.0],
        };
        // RGB pixels: red, magenta-red (hue 345), green, dark red (value too low).
        let frame = [255, 0, 0, 255, 0, 64, 0, 255, 0, 30, 0, 0];
        let h = ImageHeader::packed(Stamp::default(), 0, 4, 1, PixelEncoding::RGB8);
        assert_eq!(
            navigability(&h, &frame, &[red]).unwrap(),
            vec![255, 255, 0, 0]
        );
        let bgr: Vec<u8> = frame.chunks(3).flat_map(|p| [p[2], p[1], p[0]]).collect();
        let hb = ImageHeader {
            encoding: PixelEncoding::BGR8,
            ..h
        };
        assert_eq!(
            navigability(&hb, &bgr, &[red]).unwrap(),
            vec![255, 255, 0, 0]
        );
        let bad = HsvRange {
            value: [0.9, 0.1],
            ..red
        };
        assert_eq!(
            bad.validate().unwrap_err().to_string(),
            "config key `value` = [0.9, 0.1]: expected [min, max] with min <= max"
        );
        let dark = HsvRange {
            value: [f32::NAN, 0.1],
            ..red
        };
        assert_eq!(
            dark.validate().unwrap_err().to_string(),
            "config key `value[0]` = NaN: expected 0 <= x <= 1"
        );
    }
}
