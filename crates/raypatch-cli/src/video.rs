//! Where a sequence's frames go, one at a time as they are rendered (memory does not grow with the frame
//! count): an MP4 (H.264 from the bundled OpenH264 encoder, muxed by the `mp4` crate), an animated GIF, or
//! one PNG per frame; each file a temporary until the whole run succeeded ([`raypatch::Staged`]).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use openh264::encoder::{BitRate, Encoder, EncoderConfig, FrameRate, IntraFramePeriod, QpRange, VuiConfig};
use openh264::formats::YUVBuffer;
use openh264::OpenH264API;
use raypatch::{GifWriter, Image, Staged};

/// Frames per second of a video when neither --fps nor the camera path gives one.
pub const DEFAULT_FPS: f64 = 24.0;

/// The animated formats `--out` may name, by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VideoFormat {
    Mp4,
    Gif,
}

impl VideoFormat {
    /// The format `path`'s extension names: `.mp4` or `.gif`; `.webp` and other video extensions are an
    /// error naming what is supported.
    pub fn of(path: &Path) -> Result<Option<VideoFormat>> {
        let extension = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
        match extension.as_deref() {
            Some("mp4") => Ok(Some(VideoFormat::Mp4)),
            Some("gif") => Ok(Some(VideoFormat::Gif)),
            Some(other @ ("webp" | "webm" | "mkv" | "mov" | "avi" | "apng")) => bail!(
                "--out {}: .{other} videos are not written (the image crate encodes only still, lossless WebP); use \
                 .mp4 (H.264), .gif, or a folder of PNGs",
                path.display()
            ),
            _ => Ok(None),
        }
    }
}

/// Checks that a video of `width` x `height` can be encoded: H.264 in 4:2:0 needs even sides (no padding is
/// added, so that the video's frames are the rendered frames).
pub fn check_video_size(out: &Path, format: VideoFormat, width: usize, height: usize) -> Result<()> {
    if format == VideoFormat::Mp4 && (width % 2 == 1 || height % 2 == 1) {
        bail!(
            "--out {}: H.264 needs an even width and height, the frames are {width}x{height} (choose an even size, \
             e.g. --size {}x{})",
            out.display(),
            width + width % 2,
            height + height % 2
        );
    }
    // OpenH264 encodes up to level 5.2: 3840x2160, either way round.
    if format == VideoFormat::Mp4 && (width.max(height) > 3840 || width.min(height) > 2160) {
        bail!("--out {}: frames of {width}x{height} are larger than H.264 here takes (3840x2160)", out.display());
    }
    Ok(())
}

/// One destination of a sequence's colour frames.
pub enum FrameWriter {
    /// One PNG per frame, at these paths in order.
    Pngs {
        paths: Vec<PathBuf>,
        next: usize,
    },
    Gif(GifWriter<BufWriter<File>>),
    Mp4(Box<Mp4Writer>),
}

impl FrameWriter {
    /// A writer of `format` into `path` (created through `staged`), at `fps`.
    pub fn video(staged: &mut Staged, format: VideoFormat, path: &Path, fps: f64) -> Result<FrameWriter> {
        let file = BufWriter::new(staged.create(path)?);
        Ok(match format {
            VideoFormat::Gif => FrameWriter::Gif(GifWriter::new(file, fps)?),
            VideoFormat::Mp4 => FrameWriter::Mp4(Box::new(Mp4Writer::new(file, fps)?)),
        })
    }

    pub fn push(&mut self, staged: &mut Staged, frame: &Image) -> Result<()> {
        match self {
            FrameWriter::Pngs { paths, next } => {
                let path = &paths[*next];
                staged.create(path)?.write_all(&frame.encode_png()?).with_context(|| format!("{}", path.display()))?;
                *next += 1;
                Ok(())
            }
            FrameWriter::Gif(gif) => Ok(gif.push(frame)?),
            FrameWriter::Mp4(mp4) => mp4.push(frame),
        }
    }

    /// Ends the video (the MP4's index, the GIF's trailer) and flushes it.
    pub fn finish(self) -> Result<()> {
        match self {
            FrameWriter::Pngs { .. } => Ok(()),
            FrameWriter::Gif(gif) => Ok(gif.finish()?.flush()?),
            FrameWriter::Mp4(mp4) => mp4.finish(),
        }
    }
}

/// H.264 in an MP4, a frame at a time: OpenH264 encodes each frame (BT.601 limited range, as its RGB to YUV
/// conversion makes, and as the stream's VUI says), the `mp4` crate writes the samples and, at the end, the
/// index.
pub struct Mp4Writer {
    encoder: Encoder,
    /// The muxer, made at the first frame (it needs the stream's parameter sets), or the file until then.
    mux: Mux,
    fps: f64,
    frames: u64,
    size: Option<(usize, usize)>,
}

enum Mux {
    Waiting(BufWriter<File>),
    Writing(mp4::Mp4Writer<BufWriter<File>>),
    Finished,
}

/// The lowest quantisation parameter OpenH264's rate control takes (it raises lower ones to 12): about
/// 46 dB PSNR on the luma of the bundled model's frames; 4:2:0 chroma costs more on small frames (README).
const LOWEST_QP: u8 = 12;

/// The track's time unit per frame: the track's timescale is fps × this, so that any fps with three decimals
/// has a whole frame duration.
const TICKS_PER_FRAME: u32 = 1000;

impl Mp4Writer {
    fn new(file: BufWriter<File>, fps: f64) -> Result<Mp4Writer> {
        // As close to the rendered pixels as OpenH264 goes (a constant QP of 12; the buffer-based rate control
        // is the one that neither skips frames nor warns when told not to), a keyframe every two seconds for
        // seeking.
        let config = EncoderConfig::new()
            .max_frame_rate(FrameRate::from_hz(fps as f32))
            .bitrate(BitRate::from_bps(20_000_000))
            .qp(QpRange::new(LOWEST_QP, LOWEST_QP))
            .rate_control_mode(openh264::encoder::RateControlMode::Bufferbased)
            .skip_frames(false)
            .intra_frame_period(IntraFramePeriod::from_num_frames((2.0 * fps).round() as u32))
            .vui(VuiConfig::bt601());
        let encoder = Encoder::with_api_config(OpenH264API::from_source(), config)
            .map_err(|e| anyhow::anyhow!("cannot start the H.264 encoder: {e}"))?;
        Ok(Mp4Writer { encoder, mux: Mux::Waiting(file), fps, frames: 0, size: None })
    }

    fn push(&mut self, frame: &Image) -> Result<()> {
        let (width, height) = (frame.width(), frame.height());
        if *self.size.get_or_insert((width, height)) != (width, height) {
            bail!("an MP4's frames have one size: a {width}x{height} frame follows {:?}", self.size);
        }
        let yuv = YUVBuffer::from_vec(bt601_yuv420(frame), width, height);
        let stream = self.encoder.encode(&yuv).map_err(|e| anyhow::anyhow!("H.264 encoding failed: {e}"))?;
        let (mut sps, mut pps, mut sample, mut sync) = (None, None, Vec::new(), false);
        for layer in (0..stream.num_layers()).filter_map(|i| stream.layer(i)) {
            for nal in (0..layer.nal_count()).filter_map(|i| layer.nal_unit(i)) {
                let nal = without_start_code(nal);
                match nal.first().map(|b| b & 0x1f) {
                    Some(7) => sps = Some(nal.to_vec()),
                    Some(8) => pps = Some(nal.to_vec()),
                    Some(kind) => {
                        sync |= kind == 5;
                        // MP4 samples hold length-prefixed NAL units (AVCC), not Annex B start codes.
                        sample.extend_from_slice(&(nal.len() as u32).to_be_bytes());
                        sample.extend_from_slice(nal);
                    }
                    None => {}
                }
            }
        }
        if sample.is_empty() {
            bail!("the H.264 encoder gave no picture for frame {}", self.frames);
        }
        if let Mux::Waiting(_) = self.mux {
            let (Some(sps), Some(pps)) = (sps, pps) else {
                bail!("the H.264 encoder's first frame has no parameter sets");
            };
            let Mux::Waiting(file) = std::mem::replace(&mut self.mux, Mux::Finished) else { unreachable!() };
            let config = mp4::Mp4Config {
                major_brand: "isom".parse()?,
                minor_version: 512,
                compatible_brands: ["isom", "iso2", "avc1", "mp41"]
                    .iter()
                    .map(|b| b.parse())
                    .collect::<Result<_, _>>()?,
                timescale: 1000,
            };
            let mut mux = mp4::Mp4Writer::write_start(file, &config)?;
            mux.add_track(&mp4::TrackConfig {
                track_type: mp4::TrackType::Video,
                timescale: (self.fps * TICKS_PER_FRAME as f64).round() as u32,
                language: "und".into(),
                media_conf: mp4::MediaConfig::AvcConfig(mp4::AvcConfig {
                    width: width as u16,
                    height: height as u16,
                    seq_param_set: sps,
                    pic_param_set: pps,
                }),
            })?;
            self.mux = Mux::Writing(mux);
        }
        let Mux::Writing(mux) = &mut self.mux else { unreachable!("the muxer is made at the first frame") };
        mux.write_sample(
            1,
            &mp4::Mp4Sample {
                start_time: self.frames * TICKS_PER_FRAME as u64,
                duration: TICKS_PER_FRAME,
                rendering_offset: 0,
                is_sync: sync,
                bytes: sample.into(),
            },
        )?;
        self.frames += 1;
        Ok(())
    }

    fn finish(mut self) -> Result<()> {
        match std::mem::replace(&mut self.mux, Mux::Finished) {
            Mux::Writing(mut mux) => {
                mux.write_end()?;
                mux.into_writer().flush()?;
                Ok(())
            }
            _ => bail!("an MP4 needs at least one frame"),
        }
    }
}

/// `frame` (even sides) as I420 planes, BT.601 limited range (Y 16-235, U and V 16-240), rounded to the
/// nearest level; each chroma sample the mean of its 2x2 pixels.
fn bt601_yuv420(frame: &Image) -> Vec<u8> {
    let (width, height) = (frame.width(), frame.height());
    let level = |v: f32| v.round().clamp(0.0, 255.0) as u8;
    let mut yuv = Vec::with_capacity(width * height * 3 / 2);
    for y in 0..height {
        for x in 0..width {
            let [r, g, b] = frame.pixel(x, y).map(|c| c.clamp(0.0, 1.0) * 255.0);
            yuv.push(level(16.0 + 0.256788 * r + 0.504129 * g + 0.097906 * b));
        }
    }
    let chroma = |weights: [f32; 3]| {
        let mut plane = Vec::with_capacity(width * height / 4);
        for y in (0..height).step_by(2) {
            for x in (0..width).step_by(2) {
                let pixels = [(x, y), (x + 1, y), (x, y + 1), (x + 1, y + 1)].map(|(x, y)| frame.pixel(x, y));
                let mean = |c: usize| pixels.iter().map(|p| p[c].clamp(0.0, 1.0) * 255.0).sum::<f32>() / 4.0;
                plane.push(level(128.0 + weights[0] * mean(0) + weights[1] * mean(1) + weights[2] * mean(2)));
            }
        }
        plane
    };
    yuv.extend(chroma([-0.148223, -0.290993, 0.439216]));
    yuv.extend(chroma([0.439216, -0.367788, -0.071427]));
    yuv
}

/// A NAL unit without its Annex B start code (00 00 01 or 00 00 00 01).
fn without_start_code(nal: &[u8]) -> &[u8] {
    let zeros = nal.iter().take_while(|&&b| b == 0).count();
    if zeros >= 2 && nal.get(zeros) == Some(&1) {
        &nal[zeros + 1..]
    } else {
        nal
    }
}
