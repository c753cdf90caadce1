//! V4L2 capture (`/dev/videoN`) with memory-mapped streaming buffers, through
//! the kernel's ioctl interface directly (no libv4l, no bindgen), and the
//! conversion of the camera's YUYV or MJPEG frames to RGB8.
//!
//! No camera exists on the build machines: the conversion is tested on
//! captured buffers, and opening a missing device is tested to fail with a
//! message that says what to check.

use farsight_interfaces::msg::{ImageHeader, PixelEncoding, Stamp};
use std::ffi::CString;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};

/// Pixel formats farsight asks cameras for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum V4l2Format {
    Yuyv,
    Mjpeg,
}

impl V4l2Format {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "yuyv" => Some(Self::Yuyv),
            "mjpeg" => Some(Self::Mjpeg),
            _ => None,
        }
    }

    fn fourcc(self) -> u32 {
        let f = |s: &[u8; 4]| u32::from_le_bytes(*s);
        match self {
            Self::Yuyv => f(b"YUYV"),
            Self::Mjpeg => f(b"MJPG"),
        }
    }
}

/// A V4L2 problem, with what to do about it.
#[derive(Debug, thiserror::Error)]
pub enum V4l2Error {
    #[error("V4L2 device {0} does not exist: is the camera connected? (`ls /dev/video*` lists the devices)")]
    Missing(String),
    #[error("no permission to open {0}: run the stage as a user in the 'video' group")]
    Permission(String),
    #[error("{device}: {what} failed: {err}")]
    Ioctl {
        device: String,
        what: &'static str,
        err: std::io::Error,
    },
    #[error("{device} is not a video capture device with streaming I/O")]
    NotCapture { device: String },
    #[error(
        "{device} delivers {got_w}x{got_h} {got_fourcc}, asked for {want_w}x{want_h} {want:?}"
    )]
    FormatRefused {
        device: String,
        got_w: u32,
        got_h: u32,
        got_fourcc: String,
        want_w: u32,
        want_h: u32,
        want: V4l2Format,
    },
    #[error("{device}: frame conversion: {source}")]
    Convert {
        device: String,
        #[source]
        source: farsight_imaging::ImageError,
    },
    #[error("{device}: no frame within {timeout_ms} ms")]
    Timeout { device: String, timeout_ms: i32 },
}

/// Converts one captured buffer to packed RGB8.
pub fn convert_frame(
    format: V4l2Format,
    width: u32,
    height: u32,
    data: &[u8],
) -> Result<(ImageHeader, Vec<u8>), farsight_imaging::ImageError> {
    match format {
        V4l2Format::Yuyv => {
            let h = ImageHeader::packed(Stamp::default(), 0, width, height, PixelEncoding::YUYV);
            farsight_imaging::yuyv_to_rgb(&h, data)
        }
        V4l2Format::Mjpeg => {
            let limits = farsight_imaging::ImageLimits {
                max_width: width,
                max_height: height,
            };
            let (h, rgb) = farsight_imaging::decode_jpeg_within(data, limits)?;
            if (h.width, h.height) != (width, height) {
                return Err(farsight_imaging::ImageError::Jpeg(format!(
                    "frame is {}x{}, the stream was set up for {width}x{height}",
                    h.width, h.height
                )));
            }
            Ok((h, rgb))
        }
    }
}

// ioctl numbers: _IOC(dir, 'V', nr, size) for the structs below (64-bit layouts).
const VIDIOC_QUERYCAP: libc::c_ulong = 0x8068_5600;
const VIDIOC_S_FMT: libc::c_ulong = 0xc0d0_5605;
const VIDIOC_REQBUFS: libc::c_ulong = 0xc014_5608;
const VIDIOC_QUERYBUF: libc::c_ulong = 0xc058_5609;
const VIDIOC_QBUF: libc::c_ulong = 0xc058_560f;
const VIDIOC_DQBUF: libc::c_ulong = 0xc058_5611;
const VIDIOC_STREAMON: libc::c_ulong = 0x4004_5612;
const VIDIOC_STREAMOFF: libc::c_ulong = 0x4004_5613;
const BUF_TYPE_VIDEO_CAPTURE: u32 = 1;
const MEMORY_MMAP: u32 = 1;
const CAP_VIDEO_CAPTURE: u32 = 0x1;
const CAP_STREAMING: u32 = 0x0400_0000;

#[repr(C)]
struct Capability {
    driver: [u8; 16],
    card: [u8; 32],
    bus_info: [u8; 32],
    version: u32,
    capabilities: u32,
    device_caps: u32,
    reserved: [u32; 3],
}

#[repr(C)]
#[derive(Clone, Copy)]
struct PixFormat {
    width: u32,
    height: u32,
    pixelformat: u32,
    field: u32,
    bytesperline: u32,
    sizeimage: u32,
    colorspace: u32,
    priv_: u32,
    flags: u32,
    ycbcr_enc: u32,
    quantization: u32,
    xfer_func: u32,
}

#[repr(C)]
struct Format {
    type_: u32,
    _pad: u32,
    pix: PixFormat,
    _rest: [u8; 200 - 48],
}

#[repr(C)]
struct RequestBuffers {
    count: u32,
    type_: u32,
    memory: u32,
    capabilities: u32,
    flags: u8,
    reserved: [u8; 3],
}

#[repr(C)]
struct Buffer {
    index: u32,
    type_: u32,
    bytesused: u32,
    flags: u32,
    field: u32,
    timestamp: libc::timeval,
    timecode: [u32; 4],
    sequence: u32,
    memory: u32,
    m_offset: u64,
    length: u32,
    reserved2: u32,
    request_fd: u32,
}

const _: () = assert!(core::mem::size_of::<Capability>() == 104);
const _: () = assert!(core::mem::size_of::<Format>() == 208);
const _: () = assert!(core::mem::size_of::<RequestBuffers>() == 20);
const _: () = assert!(core::mem::size_of::<Buffer>() == 88);

fn zeroed<T>() -> T {
    // SAFETY: only used for the plain-old-data ioctl structs above.
    unsafe { core::mem::zeroed() }
}

/// An open, streaming V4L2 camera.
pub struct V4l2Camera {
    device: String,
    fd: OwnedFd,
    maps: Vec<(*mut libc::c_void, usize)>,
    pub format: V4l2Format,
    pub width: u32,
    pub height: u32,
}

// SAFETY: the mapped buffers belong to this camera alone and are only touched
// through &mut self.
unsafe impl Send for V4l2Camera {}

impl V4l2Camera {
    fn ioctl<T>(
        &self,
        what: &'static str,
        req: libc::c_ulong,
        arg: &mut T,
    ) -> Result<(), V4l2Error> {
        loop {
            // SAFETY: `arg` is the struct this request expects, sized as the kernel's.
            let r = unsafe { libc::ioctl(self.fd.as_raw_fd(), req as _, arg as *mut T) };
            if r >= 0 {
                return Ok(());
            }
            let err = std::io::Error::last_os_error();
            if err.kind() != std::io::ErrorKind::Interrupted {
                return Err(V4l2Error::Ioctl {
                    device: self.device.clone(),
                    what,
                    err,
                });
            }
        }
    }

    /// Opens `device`, sets the format and starts streaming with 4 buffers.
    pub fn open(
        device: &str,
        format: V4l2Format,
        width: u32,
        height: u32,
    ) -> Result<Self, V4l2Error> {
        let path = CString::new(device).map_err(|_| V4l2Error::Missing(device.to_string()))?;
        // SAFETY: a valid C string; the fd is owned below.
        let fd = unsafe {
            libc::open(
                path.as_ptr(),
                libc::O_RDWR | libc::O_NONBLOCK | libc::O_CLOEXEC,
            )
        };
        if fd < 0 {
            let err = std::io::Error::last_os_error();
            return Err(match err.raw_os_error() {
                Some(libc::ENOENT) | Some(libc::ENODEV) | Some(libc::ENXIO) => {
                    V4l2Error::Missing(device.to_string())
                }
                Some(libc::EACCES) | Some(libc::EPERM) => V4l2Error::Permission(device.to_string()),
                _ => V4l2Error::Ioctl {
                    device: device.to_string(),
                    what: "open",
                    err,
                },
            });
        }
        // SAFETY: fd was just opened and is not owned elsewhere.
        let fd = unsafe { OwnedFd::from_raw_fd(fd) };
        let mut cam = Self {
            device: device.to_string(),
            fd,
            maps: Vec::new(),
            format,
            width,
            height,
        };
        let mut cap: Capability = zeroed();
        cam.ioctl("VIDIOC_QUERYCAP", VIDIOC_QUERYCAP, &mut cap)?;
        let caps = if cap.device_caps != 0 {
            cap.device_caps
        } else {
            cap.capabilities
        };
        if caps & CAP_VIDEO_CAPTURE == 0 || caps & CAP_STREAMING == 0 {
            return Err(V4l2Error::NotCapture {
                device: cam.device.clone(),
            });
        }
        let mut fmt: Format = zeroed();
        fmt.type_ = BUF_TYPE_VIDEO_CAPTURE;
        fmt.pix.width = width;
        fmt.pix.height = height;
        fmt.pix.pixelformat = format.fourcc();
        cam.ioctl("VIDIOC_S_FMT", VIDIOC_S_FMT, &mut fmt)?;
        if (fmt.pix.width, fmt.pix.height, fmt.pix.pixelformat) != (width, height, format.fourcc())
        {
            return Err(V4l2Error::FormatRefused {
                device: cam.device.clone(),
                got_w: fmt.pix.width,
                got_h: fmt.pix.height,
                got_fourcc: String::from_utf8_lossy(&fmt.pix.pixelformat.to_le_bytes())
                    .into_owned(),
                want_w: width,
                want_h: height,
                want: format,
            });
        }
        let mut req = RequestBuffers {
            count: 4,
            type_: BUF_TYPE_VIDEO_CAPTURE,
            memory: MEMORY_MMAP,
            capabilities: 0,
            flags: 0,
            reserved: [0; 3],
        };
        cam.ioctl("VIDIOC_REQBUFS", VIDIOC_REQBUFS, &mut req)?;
        for index in 0..req.count {
            let mut buf: Buffer = zeroed();
            buf.type_ = BUF_TYPE_VIDEO_CAPTURE;
            buf.memory = MEMORY_MMAP;
            buf.index = index;
            cam.ioctl("VIDIOC_QUERYBUF", VIDIOC_QUERYBUF, &mut buf)?;
            // SAFETY: maps the driver's buffer `index` as the driver describes it.
            let ptr = unsafe {
                libc::mmap(
                    core::ptr::null_mut(),
                    buf.length as usize,
                    libc::PROT_READ | libc::PROT_WRITE,
                    libc::MAP_SHARED,
                    cam.fd.as_raw_fd(),
                    buf.m_offset as libc::off_t,
                )
            };
            if ptr == libc::MAP_FAILED {
                return Err(V4l2Error::Ioctl {
                    device: cam.device.clone(),
                    what: "mmap",
                    err: std::io::Error::last_os_error(),
                });
            }
            cam.maps.push((ptr, buf.length as usize));
            cam.ioctl("VIDIOC_QBUF", VIDIOC_QBUF, &mut buf)?;
        }
        let mut ty = BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        cam.ioctl("VIDIOC_STREAMON", VIDIOC_STREAMON, &mut ty)?;
        Ok(cam)
    }

    /// Waits up to `timeout_ms` for the next frame and returns it as RGB8 with
    /// the driver's capture time (monotonic clock) in nanoseconds.
    pub fn capture(&mut self, timeout_ms: i32) -> Result<(ImageHeader, Vec<u8>), V4l2Error> {
        let mut pfd = libc::pollfd {
            fd: self.fd.as_raw_fd(),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one valid pollfd.
        let n = unsafe { libc::poll(&mut pfd, 1, timeout_ms) };
        if n == 0 {
            return Err(V4l2Error::Timeout {
                device: self.device.clone(),
                timeout_ms,
            });
        }
        let mut buf: Buffer = zeroed();
        buf.type_ = BUF_TYPE_VIDEO_CAPTURE;
        buf.memory = MEMORY_MMAP;
        self.ioctl("VIDIOC_DQBUF", VIDIOC_DQBUF, &mut buf)?;
        let (ptr, len) = self.maps[buf.index as usize];
        let used = (buf.bytesused as usize).min(len);
        // SAFETY: the driver filled `used` bytes of this mapped buffer and hands
        // it to us until we queue it again below.
        let data = unsafe { core::slice::from_raw_parts(ptr as *const u8, used) };
        let converted = convert_frame(self.format, self.width, self.height, data);
        self.ioctl("VIDIOC_QBUF", VIDIOC_QBUF, &mut buf)?;
        converted.map_err(|source| V4l2Error::Convert {
            device: self.device.clone(),
            source,
        })
    }
}

impl Drop for V4l2Camera {
    fn drop(&mut self) {
        let mut ty = BUF_TYPE_VIDEO_CAPTURE as libc::c_int;
        let _ = self.ioctl("VIDIOC_STREAMOFF", VIDIOC_STREAMOFF, &mut ty);
        for (ptr, len) in self.maps.drain(..) {
            // SAFETY: unmapping what open() mapped.
            unsafe { libc::munmap(ptr, len) };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_device_is_a_clear_error() {
        let e = V4l2Camera::open("/dev/video-farsight-absent", V4l2Format::Yuyv, 640, 480)
            .err()
            .unwrap();
        assert!(matches!(e, V4l2Error::Missing(_)), "{e}");
        assert_eq!(
            e.to_string(),
            "V4L2 device /dev/video-farsight-absent does not exist: is the camera connected? (`ls /dev/video*` lists the devices)"
        );
    }

    #[test]
    fn a_file_that_is_not_a_camera_is_refused() {
        let e = V4l2Camera::open("/dev/null", V4l2Format::Yuyv, 640, 480)
            .err()
            .unwrap();
        assert!(e.to_string().contains("/dev/null"), "{e}");
    }

    #[test]
    fn captured_buffers_convert() {
        // A 2x1 YUYV buffer (white, black) and an MJPEG frame as a camera sends it.
        let (_, rgb) = convert_frame(V4l2Format::Yuyv, 2, 1, &[235, 128, 16, 128]).unwrap();
        assert_eq!(rgb, vec![255, 255, 255, 0, 0, 0]);
        let h = ImageHeader::packed(Stamp::default(), 0, 16, 8, PixelEncoding::RGB8);
        let jpeg = farsight_imaging::encode_jpeg(&h, &[90u8; 16 * 8 * 3], 90).unwrap();
        let (jh, _) = convert_frame(V4l2Format::Mjpeg, 16, 8, &jpeg).unwrap();
        assert_eq!((jh.width, jh.height), (16, 8));
        assert!(
            convert_frame(V4l2Format::Mjpeg, 32, 8, &jpeg).is_err(),
            "size must match the stream"
        );
        assert!(
            convert_frame(V4l2Format::Yuyv, 2, 1, &[235, 128]).is_err(),
            "short buffer"
        );
        assert_eq!(V4l2Format::parse("mjpeg"), Some(V4l2Format::Mjpeg));
        assert_eq!(V4l2Format::parse("h264"), None);
    }
}
