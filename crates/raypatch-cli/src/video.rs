//! Where a sequence's frames go, one at a time as they are rendered (memory does not grow with the frame
//! count): an MP4 (H.264 from the bundled OpenH264 encoder, or lossless from [`crate::h264_lossless`], muxed
//! by the `mp4` crate), an animated GIF, or one PNG per frame; each file a temporary until the whole run
//! succeeded ([`raypatch::Staged`]).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use openh264::decoder::{Decoder, DecoderConfig};
use openh264::encoder::{BitRate, Encoder, EncoderConfig, FrameRate, IntraFramePeriod, QpRange, VuiConfig};
use openh264::formats::{YUVBuffer, YUVSource};
use openh264::OpenH264API;
use raypatch::{GifWriter, Image, Staged};

use crate::h264_lossless::LosslessH264;

/// Frames per second of a video when neither --fps nor the camera path gives one.
pub const DEFAULT_FPS: f64 = 24.0;

/// The animated formats `--out` may name, by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VideoFormat {
    Mp4,
    Gif,
}

impl VideoFormat {
    /// The format `path`'s extension names: `.mp4` or `.gif`; other video extensions are an error naming why
    /// that one is not written and what is supported.
    pub fn of(path: &Path) -> Result<Option<VideoFormat>> {
        let extension = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase());
        let why = match extension.as_deref() {
            Some("mp4") => return Ok(Some(VideoFormat::Mp4)),
            Some("gif") => return Ok(Some(VideoFormat::Gif)),
            Some("webp") => "animated WebP is not written (the image crate encodes only still, lossless WebP)",
            Some("apng") => "animated PNG is not written",
            Some("webm") => "WebM needs a VP8, VP9 or AV1 encoder, which render-frame does not carry",
            Some(container @ ("mkv" | "mov" | "avi" | "m4v" | "ogv")) => {
                return Err(anyhow::anyhow!(
                    "--out {}: .{container} files are not written (the H.264 video goes into an .mp4); use .mp4, \
                     .gif, or a folder of PNGs",
                    path.display()
                ))
            }
            _ => return Ok(None),
        };
        bail!("--out {}: {why}; use .mp4 (H.264), .gif, or a folder of PNGs", path.display())
    }
}

/// How `--out NAME.mp4` encodes its frames (`--mp4`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Mp4Mode {
    /// Compact, unless its first frame decodes below [`AUTO_LEAST_PSNR`] against the render: then lossless.
    #[default]
    Auto,
    /// OpenH264's 4:2:0 (Constrained Baseline): small, every player plays it, close to the render but not exact.
    Compact,
    /// High 4:4:4 Predictive with every sample stored raw ([`crate::h264_lossless`]): exact, 3 bytes a pixel a
    /// frame; ffmpeg and Chromium play it, players without H.264's 4:4:4 profiles do not.
    Lossless,
}

impl Mp4Mode {
    pub const ALL: [Mp4Mode; 3] = [Mp4Mode::Auto, Mp4Mode::Compact, Mp4Mode::Lossless];

    pub fn name(self) -> &'static str {
        match self {
            Mp4Mode::Auto => "auto",
            Mp4Mode::Compact => "compact",
            Mp4Mode::Lossless => "lossless",
        }
    }

    pub fn from_name(name: &str) -> Option<Mp4Mode> {
        Mp4Mode::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// The least PSNR against the render, in dB, of the compact encoding's first frame that `--mp4 auto` keeps
/// it for (issue 30's bar for a video's first frame).
pub const AUTO_LEAST_PSNR: f64 = 40.0;

/// OpenH264 refuses pictures with a side under 16 pixels (one macroblock).
const COMPACT_LEAST_SIDE: usize = 16;

/// Whether the compact encoding (OpenH264, 4:2:0) takes frames of `width` x `height`: even sides (4:2:0
/// halves them; no padding is added, so that the video's frames are the rendered frames), each at least
/// [`COMPACT_LEAST_SIDE`].
fn compact_takes(width: usize, height: usize) -> bool {
    width % 2 == 0 && height % 2 == 0 && width.min(height) >= COMPACT_LEAST_SIDE
}

/// Checks, before anything is rendered, that a video of `width` x `height` can be encoded as `mp4` asks:
/// `compact` needs a size OpenH264 takes ([`compact_takes`]); `auto` and `lossless` take any size (auto is
/// lossless where compact cannot be), up to H.264's largest.
pub fn check_video_size(out: &Path, format: VideoFormat, mp4: Mp4Mode, width: usize, height: usize) -> Result<()> {
    if format != VideoFormat::Mp4 {
        return Ok(());
    }
    if mp4 == Mp4Mode::Compact && !compact_takes(width, height) {
        bail!("--out {}: {}", out.display(), compact_refusal(width, height));
    }
    // OpenH264 encodes up to level 5.2: 3840x2160, either way round; the lossless writer keeps to the same.
    if width.max(height) > 3840 || width.min(height) > 2160 {
        bail!("--out {}: frames of {width}x{height} are larger than H.264 here takes (3840x2160)", out.display());
    }
    Ok(())
}

/// Why `--mp4 compact` cannot encode `width` x `height`, with the nearest size it takes.
fn compact_refusal(width: usize, height: usize) -> String {
    let fit = |side: usize| (side + side % 2).max(COMPACT_LEAST_SIDE);
    format!(
        "--mp4 compact (H.264 4:2:0) needs an even width and height of at least {COMPACT_LEAST_SIDE} pixels, the \
         frames are {width}x{height} (choose e.g. --size {}x{}, or --mp4 lossless or auto, which take any size)",
        fit(width),
        fit(height)
    )
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
    /// A writer of `format` into `path` (created through `staged`), at `fps`; an MP4 encoded as `mp4` says.
    pub fn video(staged: &mut Staged, format: VideoFormat, path: &Path, fps: f64, mp4: Mp4Mode) -> Result<FrameWriter> {
        let file = BufWriter::new(staged.create(path)?);
        Ok(match format {
            VideoFormat::Gif => FrameWriter::Gif(GifWriter::new(file, fps)?),
            VideoFormat::Mp4 => FrameWriter::Mp4(Box::new(Mp4Writer::new(file, fps, mp4))),
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

/// H.264 in an MP4, a frame at a time: the encoder that the mode picks at the first frame encodes each
/// frame, the `mp4` crate writes the samples and, at the end, the index.
pub struct Mp4Writer {
    mode: Mp4Mode,
    /// Chosen at the first frame.
    encoder: Option<H264Encoder>,
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

enum H264Encoder {
    /// OpenH264, 4:2:0: BT.601 full range, as [`bt601_yuv420`] makes it and the stream's VUI says.
    Compact(Box<Encoder>),
    Lossless(LosslessH264),
}

/// The lowest quantisation parameter OpenH264's rate control takes (every rate-controlled mode raises lower
/// ones to 12; only its rate-control-off mode takes a lower, fixed one, which the openh264 crate does not set).
/// On the bundled model's frames it costs 0.4 dB of the first frame's PSNR at 80x60, 1.3 dB at 320x240
/// (a quantiser of 4 would win back 0.3 and 0.9 dB for 1.8 and 2.4 times the bytes).
const LOWEST_QP: u8 = 12;

/// The track's time unit per frame: the track's timescale is fps × this, so that any fps with three decimals
/// has a whole frame duration.
const TICKS_PER_FRAME: u32 = 1000;

impl H264Encoder {
    fn compact(fps: f64) -> Result<H264Encoder> {
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
            .vui(VuiConfig::bt601().full_range(true));
        let encoder = Encoder::with_api_config(OpenH264API::from_source(), config)
            .map_err(|e| anyhow::anyhow!("cannot start the H.264 encoder: {e}"))?;
        Ok(H264Encoder::Compact(Box::new(encoder)))
    }

    /// The frame's access unit: its NAL units without start codes, parameter sets among them where the
    /// stream repeats them. `rgb` is the frame's 8-bit RGB.
    fn encode(&mut self, rgb: &[u8], width: usize, height: usize) -> Result<Vec<Vec<u8>>> {
        let encoder = match self {
            H264Encoder::Lossless(lossless) => return Ok(lossless.encode(rgb)),
            H264Encoder::Compact(encoder) => encoder,
        };
        let yuv = YUVBuffer::from_vec(bt601_yuv420(rgb, width, height), width, height);
        let stream = encoder.encode(&yuv).map_err(|e| anyhow::anyhow!("H.264 encoding failed: {e}"))?;
        let mut nals = Vec::new();
        for layer in (0..stream.num_layers()).filter_map(|i| stream.layer(i)) {
            nals.extend(
                (0..layer.nal_count()).filter_map(|i| layer.nal_unit(i)).map(|n| without_start_code(n).to_vec()),
            );
        }
        Ok(nals)
    }
}

/// The encoder `mode` picks for a video whose first frame is `rgb`, and that frame's access unit: for `auto`
/// the compact one when it takes the size and its frame decodes to at least [`AUTO_LEAST_PSNR`] against `rgb`,
/// else the lossless one.
fn first_encoding(
    mode: Mp4Mode,
    fps: f64,
    rgb: &[u8],
    width: usize,
    height: usize,
) -> Result<(H264Encoder, Vec<Vec<u8>>)> {
    if mode == Mp4Mode::Compact && !compact_takes(width, height) {
        bail!("{}", compact_refusal(width, height));
    }
    if mode != Mp4Mode::Lossless && compact_takes(width, height) {
        let mut compact = H264Encoder::compact(fps)?;
        let nals = compact.encode(rgb, width, height)?;
        if mode == Mp4Mode::Compact || decoded_psnr(&nals, rgb)? >= AUTO_LEAST_PSNR {
            return Ok((compact, nals));
        }
    }
    let mut lossless = H264Encoder::Lossless(LosslessH264::new(width, height, fps));
    let nals = lossless.encode(rgb, width, height)?;
    Ok((lossless, nals))
}

/// The PSNR against `rgb` of the compact encoder's first frame (`nals`) as ffmpeg shows it: decoded by
/// OpenH264 (H.264 decoding is exact: every conforming decoder gives these planes) and turned into RGB with
/// ffmpeg's arithmetic ([`decoded_chroma_offsets`]).
fn decoded_psnr(nals: &[Vec<u8>], rgb: &[u8]) -> Result<f64> {
    let annex_b: Vec<u8> = nals.iter().flat_map(|nal| [0, 0, 0, 1].iter().chain(nal)).copied().collect();
    let mut decoder = Decoder::with_api_config(OpenH264API::from_source(), DecoderConfig::new())
        .map_err(|e| anyhow::anyhow!("cannot start the H.264 decoder: {e}"))?;
    let picture = decoder
        .decode(&annex_b)
        .map_err(|e| anyhow::anyhow!("H.264 decoding of the first frame failed: {e}"))?
        .context("the H.264 decoder gave no picture for the first frame")?;
    let (width, height) = picture.dimensions();
    let (luma_stride, chroma_stride, _) = picture.strides();
    let mut squares = 0u64;
    for (y, x) in (0..height).flat_map(|y| (0..width).map(move |x| (y, x))) {
        let luma = i32::from(picture.y()[y * luma_stride + x]);
        let chroma = y / 2 * chroma_stride + x / 2;
        let offsets = decoded_chroma_offsets(picture.u()[chroma], picture.v()[chroma]);
        for (c, offset) in offsets.into_iter().enumerate() {
            let error = (luma + offset).clamp(0, 255) - i32::from(rgb[3 * (y * width + x) + c]);
            squares += (error * error) as u64;
        }
    }
    let mse = squares as f64 / rgb.len() as f64;
    Ok(10.0 * (255.0 * 255.0 / mse).log10())
}

impl Mp4Writer {
    fn new(file: BufWriter<File>, fps: f64, mode: Mp4Mode) -> Mp4Writer {
        Mp4Writer { mode, encoder: None, mux: Mux::Waiting(file), fps, frames: 0, size: None }
    }

    fn push(&mut self, frame: &Image) -> Result<()> {
        let (width, height) = (frame.width(), frame.height());
        if *self.size.get_or_insert((width, height)) != (width, height) {
            bail!("an MP4's frames have one size: a {width}x{height} frame follows {:?}", self.size);
        }
        let rgb = frame.to_rgb8();
        let nals = match &mut self.encoder {
            Some(encoder) => encoder.encode(&rgb, width, height)?,
            None => {
                let (encoder, nals) = first_encoding(self.mode, self.fps, &rgb, width, height)?;
                self.encoder = Some(encoder);
                nals
            }
        };
        let (mut sps, mut pps, mut sample, mut sync) = (None, None, Vec::new(), false);
        for nal in nals {
            match nal.first().map(|b| b & 0x1f) {
                Some(7) => sps = Some(nal),
                Some(8) => pps = Some(nal),
                Some(kind) => {
                    sync |= kind == 5;
                    // MP4 samples hold length-prefixed NAL units (AVCC), not Annex B start codes.
                    sample.extend_from_slice(&(nal.len() as u32).to_be_bytes());
                    sample.extend_from_slice(&nal);
                }
                None => {}
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

/// A frame's 8-bit RGB (`width` x `height`, even sides) as I420 planes, BT.601 full range (0-255, as the stream's VUI says): each chroma
/// sample from the mean of its 2x2 pixels, then each pixel's Y the level whose decoded RGB is nearest its own
/// ("luma adjustment", Ström et al. 2016), so that luma takes up what it can of the error the shared chroma
/// leaves. In full range every Y level moves each decoded channel by exactly one level (255/219 in limited
/// range). Against limited range with Y from each pixel's own colour, the first frame gains 0.5 dB at 80x60
/// and 1.4 dB at 320x240 (docs/CAMERA_PATHS.md), most of it from the full range; at 80x60 the bundled scene
/// stays under 40 dB, as 4:2:0 cannot do better there (tests/video.rs, `chroma_420_ceiling`): `--mp4 auto` writes
/// it lossless.
fn bt601_yuv420(rgb: &[u8], width: usize, height: usize) -> Vec<u8> {
    let at = |x: usize, y: usize| {
        let i = 3 * (y * width + x);
        [rgb[i], rgb[i + 1], rgb[i + 2]].map(i32::from)
    };
    let mut yuv = vec![0u8; width * height * 3 / 2];
    let (luma, chroma) = yuv.split_at_mut(width * height);
    let (u_plane, v_plane) = chroma.split_at_mut(width * height / 4);
    for by in 0..height / 2 {
        for bx in 0..width / 2 {
            let pixels = [(0, 0), (1, 0), (0, 1), (1, 1)].map(|(dx, dy)| (2 * bx + dx, 2 * by + dy));
            let mean = |c: usize| pixels.iter().map(|&(x, y)| at(x, y)[c] as f32).sum::<f32>() / 4.0;
            let (r, g, b) = (mean(0), mean(1), mean(2));
            let level = |v: f32| v.round().clamp(0.0, 255.0) as u8;
            let u = level(128.0 - 0.168736 * r - 0.331264 * g + 0.5 * b);
            let v = level(128.0 + 0.5 * r - 0.418688 * g - 0.081312 * b);
            u_plane[by * width / 2 + bx] = u;
            v_plane[by * width / 2 + bx] = v;
            let offsets = decoded_chroma_offsets(u, v);
            for (x, y) in pixels {
                luma[y * width + x] = nearest_luma(at(x, y), offsets);
            }
        }
    }
    yuv
}

/// What a decoder adds to Y for R, G and B at chroma (`u`, `v`), full-range BT.601. Luma adjustment needs a
/// model of the decoder; this is FFmpeg's libswscale, which `ffmpeg -i video.mp4 frame.png` (and
/// `-pix_fmt rgb24`) uses: nearest-neighbour chroma (each chroma sample repeated over its 2x2 pixels, siting
/// ignored) and its fixed-point arithmetic (ff_yuv2rgb_c_init_tables' 13-bit coefficients, 104597, 132201,
/// 25675 and 53279 / 65536 × 224/255; the x86 code's `pmulhw` floors). Checked bit-exact against FFmpeg 5.1's
/// output for random planes. Decoders that interpolate chroma (browsers) gain from the full range what the
/// adjustment, made for repeated chroma, costs them: ffmpeg's bilinear chroma
/// (`-sws_flags bilinear+full_chroma_int+accurate_rnd`) shows these frames within 0.05 dB of before.
fn decoded_chroma_offsets(u: u8, v: u8) -> [i32; 3] {
    let (u, v) = (8 * (i32::from(u) - 128), 8 * (i32::from(v) - 128));
    [(v * 11485) >> 16, ((u * -2819) >> 16) + ((v * -5850) >> 16), (u * 14516) >> 16]
}

/// The Y level (0-255) whose decoded pixel, `Y + offsets` per channel clamped to 0-255, has the least squared
/// error from `target`.
fn nearest_luma(target: [i32; 3], offsets: [i32; 3]) -> u8 {
    let wanted = [0, 1, 2].map(|c| target[c] - offsets[c]);
    // Below the lowest level a channel wants every channel's error only falls as Y rises, above the highest it
    // only grows.
    let low = wanted.into_iter().min().unwrap().clamp(0, 255);
    let high = wanted.into_iter().max().unwrap().clamp(0, 255);
    if (0..3).all(|c| low + offsets[c] >= 0 && high + offsets[c] <= 255) {
        // No channel clamps in between: the error is a parabola, least at the level nearest the mean.
        return ((wanted.iter().sum::<i32>() + 1).div_euclid(3)).clamp(low, high) as u8;
    }
    let error = |y: i32| (0..3).map(|c| ((y + offsets[c]).clamp(0, 255) - target[c]).pow(2)).sum::<i32>();
    (low..=high).min_by_key(|&y| error(y)).unwrap() as u8
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A reproducible stream of bytes (no rand dependency).
    fn bytes(seed: u64) -> impl Iterator<Item = u8> {
        let mut state = seed;
        std::iter::repeat_with(move || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 56) as u8
        })
    }

    #[test]
    fn nearest_luma_is_the_best_of_all_levels() {
        let mut next = bytes(1);
        for _ in 0..20_000 {
            let target = [0; 3].map(|_| i32::from(next.next().unwrap()));
            let offsets = decoded_chroma_offsets(next.next().unwrap(), next.next().unwrap());
            let error = |y: i32| (0..3).map(|c| ((y + offsets[c]).clamp(0, 255) - target[c]).pow(2)).sum::<i32>();
            let best = (0..=255).map(error).min().unwrap();
            assert_eq!(error(i32::from(nearest_luma(target, offsets))), best, "{target:?} {offsets:?}");
        }
    }

    #[test]
    fn auto_keeps_compact_for_smooth_frames_and_goes_lossless_for_noise() {
        let (width, height) = (32, 32);
        let smooth: Vec<u8> =
            (0..width * height).flat_map(|i| [(4 * (i % width)) as u8, (4 * (i / width)) as u8, 128]).collect();
        let noise: Vec<u8> = bytes(3).take(3 * width * height).collect();
        let lossless = |rgb: &[u8]| {
            let (encoder, _) = first_encoding(Mp4Mode::Auto, 24.0, rgb, width, height).unwrap();
            matches!(encoder, H264Encoder::Lossless(_))
        };
        assert!(!lossless(&smooth));
        assert!(lossless(&noise));
        let (compact, _) = first_encoding(Mp4Mode::Compact, 24.0, &noise, width, height).unwrap();
        assert!(matches!(compact, H264Encoder::Compact(_)), "compact is kept whatever its PSNR");
    }

    #[test]
    fn flat_colours_decode_to_themselves_within_a_level() {
        let mut next = bytes(2);
        for _ in 0..2_000 {
            let rgb = [0; 3].map(|_| next.next().unwrap());
            let yuv = bt601_yuv420(&rgb.repeat(4), 2, 2);
            let offsets = decoded_chroma_offsets(yuv[4], yuv[5]);
            let decoded = [0, 1, 2].map(|c| (i32::from(yuv[0]) + offsets[c]).clamp(0, 255));
            let worst = (0..3).map(|c| (decoded[c] - i32::from(rgb[c])).abs()).max().unwrap();
            assert!(worst <= 1, "{rgb:?} decodes to {decoded:?}");
        }
    }
}
