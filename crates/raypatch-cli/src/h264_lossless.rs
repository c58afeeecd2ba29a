//! H.264 that decodes to exactly the RGB it was given, written without an encoder: High 4:4:4 Predictive
//! (profile_idc 244), 8 bits, every frame one IDR slice whose macroblocks are all I_PCM (their samples stored
//! raw: no prediction, no transform, nothing to search), CAVLC. The three planes are G, B and R, as the VUI's
//! matrix_coefficients 0 (identity, "GBR") maps them, in full range; the VUI also names BT.709 primaries and
//! the sRGB transfer, without which Chromium shows the planes in wrong colours (ffmpeg is exact either way).
//! A frame costs 3 bytes a pixel and 2 bytes a macroblock. Sides that are not multiples of 16 are cropped by
//! the SPS (frame_cropping), the macroblocks past the frame filled with its edge pixels.

/// Bits most significant first, for the fixed-width and exp-Golomb fields of parameter sets and slice headers.
#[derive(Default)]
struct BitWriter {
    bytes: Vec<u8>,
    /// Bits used of the last byte, 0 when the writer is at a byte boundary.
    used: u32,
}

impl BitWriter {
    fn bit(&mut self, one: bool) {
        if self.used == 0 {
            self.bytes.push(0);
        }
        if one {
            *self.bytes.last_mut().expect("a byte was pushed") |= 0x80 >> self.used;
        }
        self.used = (self.used + 1) % 8;
    }

    /// u(n): `value`'s lowest `count` bits.
    fn bits(&mut self, count: u32, value: u64) {
        for i in (0..count).rev() {
            self.bit(value >> i & 1 == 1);
        }
    }

    /// ue(v): unsigned exp-Golomb, `value + 1` in binary after as many zeros as it has bits after its first.
    fn ue(&mut self, value: u32) {
        let coded = u64::from(value) + 1;
        let length = 64 - coded.leading_zeros();
        self.bits(length - 1, 0);
        self.bits(length, coded);
    }

    /// se(v): signed exp-Golomb, 1, -1, 2, -2, ... as ue 1, 2, 3, 4, ...
    fn se(&mut self, value: i32) {
        let magnitude = value.unsigned_abs();
        self.ue(if value > 0 { 2 * magnitude - 1 } else { 2 * magnitude });
    }

    /// Zero bits up to the next byte boundary (the unused bits of the last byte are zeros already).
    fn align_with_zeros(&mut self) {
        self.used = 0;
    }

    fn aligned_bytes(&mut self, bytes: impl IntoIterator<Item = u8>) {
        debug_assert_eq!(self.used, 0, "raw bytes start at a byte boundary");
        self.bytes.extend(bytes);
    }

    /// The RBSP: these bits, a stop bit and zeros to the byte boundary (rbsp_trailing_bits).
    fn finish(mut self) -> Vec<u8> {
        self.bit(true);
        self.bytes
    }
}

/// A NAL unit without start code (MP4 samples and avcC hold them length-prefixed): its header byte and the RBSP
/// with emulation prevention (an 03 after two zero bytes that precede a byte up to 03, so that no start code
/// appears inside).
fn nal_unit(nal_ref_idc: u8, nal_unit_type: u8, rbsp: &[u8]) -> Vec<u8> {
    let mut nal = Vec::with_capacity(rbsp.len() + rbsp.len() / 64 + 1);
    nal.push(nal_ref_idc << 5 | nal_unit_type);
    let mut zeros = 0;
    for &byte in rbsp {
        if zeros == 2 && byte <= 3 {
            nal.push(3);
            zeros = 0;
        }
        nal.push(byte);
        zeros = if byte == 0 { zeros + 1 } else { 0 };
    }
    nal
}

const NAL_SLICE_IDR: u8 = 5;
const NAL_SPS: u8 = 7;
const NAL_PPS: u8 = 8;
/// The highest nal_ref_idc: parameter sets and IDR slices are references.
const REFERENCE: u8 = 3;
/// mb_type of an I_PCM macroblock in an I slice.
const I_PCM: u32 = 25;
/// Bits of one I_PCM macroblock: mb_type (9 bits) and its alignment, then 3 planes of 16x16 bytes.
const MACROBLOCK_BITS: u64 = 16 + 3 * 256 * 8;

/// H.264's levels (Table A-1), lowest first: level_idc, most macroblocks a frame, most macroblocks a second,
/// most bits a second in units of 4800 (High 4:4:4's cpbBrVclFactor). Level 1b is left out.
const LEVELS: [(u8, u64, u64, u64); 18] = [
    (10, 99, 1_485, 64),
    (11, 396, 3_000, 192),
    (12, 396, 6_000, 384),
    (13, 396, 11_880, 768),
    (20, 396, 11_880, 2_000),
    (21, 792, 19_800, 4_000),
    (22, 1_620, 20_250, 4_000),
    (30, 1_620, 40_500, 10_000),
    (31, 3_600, 108_000, 14_000),
    (32, 5_120, 216_000, 20_000),
    (40, 8_192, 245_760, 20_000),
    (41, 8_192, 245_760, 50_000),
    (42, 8_704, 522_240, 50_000),
    (50, 22_080, 589_824, 135_000),
    (51, 36_864, 983_040, 240_000),
    (52, 36_864, 2_073_600, 240_000),
    (60, 139_264, 4_177_920, 240_000),
    (61, 139_264, 8_355_840, 480_000),
];

/// The lowest level whose limits hold `macroblocks` a frame at `fps`, else the highest (6.2: raw frames at
/// large sizes and rates exceed every level's bit rate; decoders that play them do not check it).
fn level_idc(macroblocks: u64, fps: f64) -> u8 {
    let per_second = (macroblocks as f64 * fps).ceil() as u64;
    let bits_per_second = (macroblocks as f64 * MACROBLOCK_BITS as f64 * fps).ceil() as u64;
    LEVELS
        .iter()
        .find(|&&(_, frame, rate, bit_rate)| {
            macroblocks <= frame && per_second <= rate && bits_per_second <= bit_rate * 4800
        })
        .map_or(62, |&(idc, ..)| idc)
}

/// Writes frames of one size as lossless H.264, one access unit each.
pub struct LosslessH264 {
    width: usize,
    height: usize,
    level_idc: u8,
    frames: u64,
}

impl LosslessH264 {
    pub fn new(width: usize, height: usize, fps: f64) -> LosslessH264 {
        let macroblocks = (width.div_ceil(16) * height.div_ceil(16)) as u64;
        LosslessH264 { width, height, level_idc: level_idc(macroblocks, fps), frames: 0 }
    }

    /// The next frame's access unit, its NAL units without start codes: at the first frame the SPS and PPS,
    /// then every frame an IDR slice. `rgb` is the frame's 8-bit RGB, rows top first.
    pub fn encode(&mut self, rgb: &[u8]) -> Vec<Vec<u8>> {
        assert_eq!(rgb.len(), 3 * self.width * self.height, "a frame of {}x{}", self.width, self.height);
        let mut nals = Vec::with_capacity(3);
        if self.frames == 0 {
            nals.push(self.sps());
            nals.push(pps());
        }
        nals.push(self.idr_slice(rgb));
        self.frames += 1;
        nals
    }

    fn sps(&self) -> Vec<u8> {
        let (mbs_wide, mbs_high) = (self.width.div_ceil(16), self.height.div_ceil(16));
        let mut b = BitWriter::default();
        b.bits(8, 244); // profile_idc: High 4:4:4 Predictive
        b.bits(8, 0); // constraint_set flags
        b.bits(8, self.level_idc.into());
        b.ue(0); // seq_parameter_set_id
        b.ue(3); // chroma_format_idc: 4:4:4
        b.bit(false); // separate_colour_plane_flag
        b.ue(0); // bit_depth_luma_minus8
        b.ue(0); // bit_depth_chroma_minus8
        b.bit(false); // qpprime_y_zero_transform_bypass_flag (I_PCM needs no bypass)
        b.bit(false); // seq_scaling_matrix_present_flag
        b.ue(0); // log2_max_frame_num_minus4: frame_num is always 0 in IDR pictures
        b.ue(2); // pic_order_cnt_type 2: output order is decoding order
        b.ue(1); // max_num_ref_frames
        b.bit(false); // gaps_in_frame_num_value_allowed_flag
        b.ue(mbs_wide as u32 - 1);
        b.ue(mbs_high as u32 - 1);
        b.bit(true); // frame_mbs_only_flag
        b.bit(true); // direct_8x8_inference_flag
                     // In 4:4:4 frames the crop unit is one pixel each way.
        let (crop_right, crop_bottom) = (16 * mbs_wide - self.width, 16 * mbs_high - self.height);
        b.bit(crop_right + crop_bottom > 0); // frame_cropping_flag
        if crop_right + crop_bottom > 0 {
            for offset in [0, crop_right, 0, crop_bottom] {
                b.ue(offset as u32); // left, right, top, bottom
            }
        }
        b.bit(true); // vui_parameters_present_flag
        b.bit(false); // aspect_ratio_info_present_flag
        b.bit(false); // overscan_info_present_flag
        b.bit(true); // video_signal_type_present_flag
        b.bits(3, 5); // video_format: unspecified
        b.bit(true); // video_full_range_flag
        b.bit(true); // colour_description_present_flag
        b.bits(8, 1); // colour_primaries: BT.709 (sRGB's)
        b.bits(8, 13); // transfer_characteristics: sRGB (IEC 61966-2-1)
        b.bits(8, 0); // matrix_coefficients: identity, the planes are G, B, R
        b.bit(false); // chroma_loc_info_present_flag
        b.bit(false); // timing_info_present_flag: the MP4 holds the timing
        b.bit(false); // nal_hrd_parameters_present_flag
        b.bit(false); // vcl_hrd_parameters_present_flag
        b.bit(false); // pic_struct_present_flag
        b.bit(true); // bitstream_restriction_flag: no reordering, so decoders need not hold frames back
        b.bit(true); // motion_vectors_over_pic_boundaries_flag
        b.ue(0); // max_bytes_per_pic_denom: no limit
        b.ue(0); // max_bits_per_mb_denom: no limit
        b.ue(16); // log2_max_mv_length_horizontal
        b.ue(16); // log2_max_mv_length_vertical
        b.ue(0); // max_num_reorder_frames
        b.ue(1); // max_dec_frame_buffering
        nal_unit(REFERENCE, NAL_SPS, &b.finish())
    }

    fn idr_slice(&self, rgb: &[u8]) -> Vec<u8> {
        let (mbs_wide, mbs_high) = (self.width.div_ceil(16), self.height.div_ceil(16));
        let mut b = BitWriter::default();
        b.bytes.reserve(mbs_wide * mbs_high * (MACROBLOCK_BITS as usize / 8) + 16);
        b.ue(0); // first_mb_in_slice
        b.ue(7); // slice_type: I, as every slice of the picture
        b.ue(0); // pic_parameter_set_id
        b.bits(4, 0); // frame_num
        b.ue((self.frames % 2) as u32); // idr_pic_id: consecutive IDR pictures differ
        b.bit(false); // no_output_of_prior_pics_flag
        b.bit(false); // long_term_reference_flag
        b.se(0); // slice_qp_delta
        b.ue(1); // disable_deblocking_filter_idc: off (I_PCM samples are not filtered anyway)
        let (width, height) = (self.width, self.height);
        for (my, mx) in (0..mbs_high).flat_map(|my| (0..mbs_wide).map(move |mx| (my, mx))) {
            b.ue(I_PCM);
            b.align_with_zeros(); // pcm_alignment_zero_bits
                                  // The planes in coding order G, B, R; each 16x16 in raster order, the frame's edge repeated past it.
            for channel in [1, 2, 0] {
                for y in (16 * my..16 * my + 16).map(|y| y.min(height - 1)) {
                    let row = &rgb[3 * y * width..3 * (y + 1) * width];
                    b.aligned_bytes((16 * mx..16 * mx + 16).map(|x| row[3 * x.min(width - 1) + channel]));
                }
            }
        }
        nal_unit(REFERENCE, NAL_SLICE_IDR, &b.finish())
    }
}

fn pps() -> Vec<u8> {
    let mut b = BitWriter::default();
    b.ue(0); // pic_parameter_set_id
    b.ue(0); // seq_parameter_set_id
    b.bit(false); // entropy_coding_mode_flag: CAVLC
    b.bit(false); // bottom_field_pic_order_in_frame_present_flag
    b.ue(0); // num_slice_groups_minus1
    b.ue(0); // num_ref_idx_l0_default_active_minus1
    b.ue(0); // num_ref_idx_l1_default_active_minus1
    b.bit(false); // weighted_pred_flag
    b.bits(2, 0); // weighted_bipred_idc
    b.se(0); // pic_init_qp_minus26
    b.se(0); // pic_init_qs_minus26
    b.se(0); // chroma_qp_index_offset
    b.bit(true); // deblocking_filter_control_present_flag: the slices turn it off
    b.bit(false); // constrained_intra_pred_flag
    b.bit(false); // redundant_pic_cnt_present_flag
    nal_unit(REFERENCE, NAL_PPS, &b.finish())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bit_string(write: impl FnOnce(&mut BitWriter)) -> String {
        let mut b = BitWriter::default();
        write(&mut b);
        let used = if b.used == 0 { 8 * b.bytes.len() } else { 8 * (b.bytes.len() - 1) + b.used as usize };
        b.bytes.iter().map(|byte| format!("{byte:08b}")).collect::<String>()[..used].to_string()
    }

    #[test]
    fn exp_golomb_codes_are_the_standards() {
        // H.264 Table 9-2 and 9-3.
        let unsigned =
            [(0, "1"), (1, "010"), (2, "011"), (3, "00100"), (6, "00111"), (7, "0001000"), (25, "000011010")];
        for (value, code) in unsigned {
            assert_eq!(bit_string(|b| b.ue(value)), code, "ue({value})");
        }
        let signed = [(0, "1"), (1, "010"), (-1, "011"), (2, "00100"), (-2, "00101"), (3, "00110")];
        for (value, code) in signed {
            assert_eq!(bit_string(|b| b.se(value)), code, "se({value})");
        }
        assert_eq!(bit_string(|b| b.ue(u32::MAX)), format!("{}1{}", "0".repeat(32), "0".repeat(32)));
        assert_eq!(bit_string(|b| b.bits(4, 0b1011)), "1011");
    }

    #[test]
    fn rbsp_ends_in_a_stop_bit_and_raw_bytes_follow_alignment() {
        let mut b = BitWriter::default();
        b.ue(25);
        b.align_with_zeros();
        b.aligned_bytes([0xAB]);
        assert_eq!(b.finish(), [0b0000_1101, 0b0000_0000, 0xAB, 0x80]);
    }

    #[test]
    fn emulation_prevention_breaks_every_start_code() {
        assert_eq!(
            nal_unit(3, 5, &[0, 0, 1, 0, 0, 0, 0, 0, 3, 0, 0, 4]),
            [0x65, 0, 0, 3, 1, 0, 0, 3, 0, 0, 3, 0, 3, 0, 0, 4]
        );
    }

    #[test]
    fn levels_follow_size_and_rate() {
        // 80x60 (20 macroblocks) at 24 fps: 2.96 Mbit/s, over level 1.2's 1.84 (384 x 4800), within 1.3's 3.69.
        assert_eq!(level_idc(20, 24.0), 13);
        // 1920x1080 (8160 macroblocks) at 24 fps needs 1.2 Gbit/s: level 6.1.
        assert_eq!(level_idc(8160, 24.0), 61);
        assert_eq!(level_idc(32_400, 100.0), 62);
    }

    #[test]
    fn frames_are_stored_exactly_with_the_edge_repeated() {
        let (width, height) = (18, 17);
        let rgb: Vec<u8> = (0..3 * width * height).map(|i| (i * 7 % 251) as u8).collect();
        let mut writer = LosslessH264::new(width, height, 24.0);
        let first = writer.encode(&rgb);
        assert_eq!(first.iter().map(|n| n[0] & 0x1f).collect::<Vec<_>>(), [7, 8, 5]);
        assert_eq!(writer.encode(&rgb).len(), 1, "parameter sets once");
        // The slice's RBSP: emulation prevention undone.
        let mut rbsp = Vec::new();
        let mut zeros = 0;
        for &byte in &first[2][1..] {
            if zeros == 2 && byte == 3 {
                zeros = 0;
                continue;
            }
            rbsp.push(byte);
            zeros = if byte == 0 { zeros + 1 } else { 0 };
        }
        // The last macroblock, before the stop bit: its mb_type, then the G, B and R planes.
        let end = rbsp.len() - 1;
        assert_eq!(rbsp[end], 0x80);
        assert_eq!(rbsp[end - 770..end - 768], [0b0000_1101, 0]);
        let sample =
            |channel: usize, x: usize, y: usize| rgb[3 * (y.min(height - 1) * width + x.min(width - 1)) + channel];
        for (plane, channel) in [1, 2, 0].into_iter().enumerate() {
            for i in 0..256 {
                assert_eq!(
                    rbsp[end - 768 + 256 * plane + i],
                    sample(channel, 16 + i % 16, 16 + i / 16),
                    "{channel} {i}"
                );
            }
        }
    }
}
