//! The zip archive of a `torch.save` checkpoint (PyTorch >= 1.6): entries under one top folder
//! (`archive/data.pkl`, `archive/data/N`, `archive/byteorder`, ...), stored or deflated. Everything is checked
//! from the central directory before an entry is read, as the Python converter checks it: the entries together
//! may inflate to at most [`MAX_INFLATION`] times the file's size + [`INFLATION_SLACK`] (a decompression bomb is
//! refused unread), no data may come before the first entry (PyTorch and Python's zipfile would then read
//! different entries), and an entry is read only up to its declared size, which it must match exactly (its CRC
//! is checked).
//!
//! Read here rather than by a zip library, so that the work is linear in the bytes read whatever the file holds
//! (issue 50: a general reader searches backwards for any end-of-central-directory signature and retries from
//! each, which a comment full of signatures made quadratic). Nothing is searched for: the end record is the last
//! one in the file's final [`MAX_TAIL`] bytes whose comment reaches exactly to the end of the file (one read of
//! that tail, one pass over it), the zip64 records are where the end record's locator says, the central
//! directory where the end record says (read once, its entries counted against its size), each entry's local
//! header where its directory entry says. Every loop runs over bytes already read and advances by at least one
//! field each step.

use std::collections::HashMap;
use std::io::{Read, Seek, SeekFrom};

use flate2::read::DeflateDecoder;

/// Entries may inflate to at most this many times the file's size ...
pub const MAX_INFLATION: u64 = 4;
/// ... plus this many bytes (torch.save stores entries uncompressed: its archives inflate by a factor of 1).
pub const INFLATION_SLACK: u64 = 64 << 20;
/// The end-of-central-directory record: its fixed part, and with the longest comment the format allows. The
/// record is looked for in the file's last `MAX_TAIL` bytes only.
pub const EOCD_LEN: usize = 22;
pub const MAX_TAIL: usize = EOCD_LEN + u16::MAX as usize;
/// The fixed part of a central directory header (its smallest size) and of a local header.
const CDH_LEN: usize = 46;
const LOCAL_LEN: usize = 30;
/// The zip64 end-of-central-directory record's fixed part and its locator.
const ZIP64_EOCD_LEN: usize = 56;
const ZIP64_LOCATOR_LEN: usize = 20;

const EOCD_SIG: &[u8; 4] = b"PK\x05\x06";
const ZIP64_EOCD_SIG: &[u8; 4] = b"PK\x06\x06";
const ZIP64_LOCATOR_SIG: &[u8; 4] = b"PK\x06\x07";
const CDH_SIG: &[u8; 4] = b"PK\x01\x02";
const LOCAL_SIG: &[u8; 4] = b"PK\x03\x04";

const DISPLACED: &str =
    "a zip archive with data before its entries or a displaced central directory, not as torch.save writes it";

/// An entry as its central directory header declares it.
#[derive(Debug, Clone)]
struct Entry {
    name: String,
    method: u16,
    crc: u32,
    compressed: u64,
    size: u64,
    local: u64,
}

/// An opened, checked checkpoint archive.
pub struct Archive<R: Read + Seek> {
    reader: R,
    entries: Vec<Entry>,
    /// Entry index by name (a repeated name: the last, as Python's zipfile takes it).
    by_name: HashMap<String, usize>,
    /// Where the central directory starts: every entry's data ends before it.
    directory: u64,
    /// The top folder of the entries (`archive` for torch.save of PyTorch >= 2; older versions used the file's
    /// name), with its slash.
    prefix: String,
    /// The declared size of all entries: what the archive inflates to.
    pub inflated: u64,
}

/// Little-endian fields of a record already read.
struct Fields<'a>(&'a [u8]);

impl Fields<'_> {
    fn u16(&self, at: usize) -> u16 {
        u16::from_le_bytes([self.0[at], self.0[at + 1]])
    }
    fn u32(&self, at: usize) -> u32 {
        u32::from_le_bytes(self.0[at..at + 4].try_into().unwrap())
    }
    fn u64(&self, at: usize) -> u64 {
        u64::from_le_bytes(self.0[at..at + 8].try_into().unwrap())
    }
}

fn unreadable(why: impl std::fmt::Display) -> String {
    format!("not a readable zip archive ({why})")
}

/// Reads exactly `n` bytes at `at`.
fn read_at<R: Read + Seek>(reader: &mut R, at: u64, n: usize) -> Result<Vec<u8>, String> {
    reader.seek(SeekFrom::Start(at)).map_err(unreadable)?;
    let mut bytes = vec![0u8; n];
    reader.read_exact(&mut bytes).map_err(unreadable)?;
    Ok(bytes)
}

/// The offset in `tail` of the end-of-central-directory record: the last signature whose comment length
/// reaches exactly to the end of `tail` (the end of the file). One pass from the end, O(1) per position.
pub fn find_eocd(tail: &[u8]) -> Option<usize> {
    let last = tail.len().checked_sub(EOCD_LEN)?;
    (0..=last).rev().find(|&at| {
        &tail[at..at + 4] == EOCD_SIG && usize::from(Fields(tail).u16(at + 20)) == tail.len() - at - EOCD_LEN
    })
}

/// The name of a compression method, for messages.
fn method_name(method: u16) -> String {
    let known = match method {
        1 => "shrink",
        6 => "implode",
        9 => "deflate64",
        12 => "bzip2",
        14 => "lzma",
        93 => "zstd",
        95 => "xz",
        99 => "AES encryption",
        _ => "",
    };
    if known.is_empty() { format!("method {method}") } else { format!("method {method} ({known})") }
}

/// Reads the zip64 extra field (id 1) of a central directory header: the 64-bit values of the fields that are
/// 0xFFFFFFFF in the header, in the format's order. Each step advances past one field: linear in `extra`.
fn zip64_extra(extra: &[u8], values: [&mut u64; 3]) -> Result<(), String> {
    let mut at = 0;
    while extra.len() - at >= 4 {
        let f = Fields(&extra[at..]);
        let (id, len) = (f.u16(0), usize::from(f.u16(2)));
        let body = extra.get(at + 4..at + 4 + len).ok_or("an extra field runs past the header's extra data")?;
        if id == 1 {
            let mut words = body.chunks_exact(8).map(|w| u64::from_le_bytes(w.try_into().unwrap()));
            for value in values {
                if *value == 0xFFFF_FFFF {
                    *value = words.next().ok_or("its zip64 extra field lacks a size or offset it should hold")?;
                }
            }
            return Ok(());
        }
        at += 4 + len;
    }
    Ok(())
}

impl<R: Read + Seek> Archive<R> {
    /// Opens the archive of `len` bytes in `reader` and checks its central directory. Reads the file's last
    /// [`MAX_TAIL`] bytes, the zip64 records if any, and the central directory, each once.
    pub fn open(mut reader: R, len: u64) -> Result<Archive<R>, String> {
        let tail_len = len.min(MAX_TAIL as u64) as usize;
        let tail_at = len - tail_len as u64;
        let tail = read_at(&mut reader, tail_at, tail_len)?;
        let at = find_eocd(&tail).ok_or_else(|| {
            unreadable(format!(
                "no end-of-central-directory record whose comment ends the file, in its last {tail_len} bytes"
            ))
        })?;
        let eocd_pos = tail_at + at as u64;
        let f = Fields(&tail[at..]);
        let (mut disk, mut cd_disk) = (u32::from(f.u16(4)), u32::from(f.u16(6)));
        let (mut on_disk, mut count) = (u64::from(f.u16(8)), u64::from(f.u16(10)));
        let (mut cd_size, mut cd_offset) = (u64::from(f.u32(12)), u64::from(f.u32(16)));
        let mut dir_end = eocd_pos;
        // The zip64 locator, where Python's zipfile looks for it: just before the end record.
        if let Some(locator_pos) = eocd_pos.checked_sub(ZIP64_LOCATOR_LEN as u64) {
            let locator = match locator_pos.checked_sub(tail_at) {
                Some(i) => tail[i as usize..][..ZIP64_LOCATOR_LEN].to_vec(),
                None => read_at(&mut reader, locator_pos, ZIP64_LOCATOR_LEN)?,
            };
            if &locator[..4] == ZIP64_LOCATOR_SIG {
                let l = Fields(&locator);
                if l.u32(4) != 0 || l.u32(16) > 1 {
                    return Err("a multi-disk zip archive, not as torch.save writes it".into());
                }
                let record_pos = l.u64(8);
                if record_pos.checked_add(ZIP64_EOCD_LEN as u64).is_none_or(|end| end > locator_pos) {
                    return Err(unreadable("its zip64 end record would overlap its locator"));
                }
                let record = read_at(&mut reader, record_pos, ZIP64_EOCD_LEN)?;
                if &record[..4] != ZIP64_EOCD_SIG {
                    return Err(unreadable("no zip64 end record where its locator says"));
                }
                let r = Fields(&record);
                (disk, cd_disk) = (r.u32(16), r.u32(20));
                (on_disk, count, cd_size, cd_offset) = (r.u64(24), r.u64(32), r.u64(40), r.u64(48));
                dir_end = record_pos;
            }
        }
        if disk != 0 || cd_disk != 0 || on_disk != count {
            return Err("a multi-disk zip archive, not as torch.save writes it".into());
        }
        match cd_offset.checked_add(cd_size) {
            Some(end) if end == dir_end => {}
            Some(end) if end < dir_end => return Err(DISPLACED.into()),
            _ => return Err(unreadable("its central directory would end past its end record")),
        }
        if count > cd_size / CDH_LEN as u64 {
            return Err(unreadable(format!("{count} entries declared in a {cd_size}-byte central directory")));
        }
        // At most the file's size (it ends before the end record).
        let cd = read_at(&mut reader, cd_offset, cd_size as usize)?;
        let mut entries = Vec::with_capacity(count as usize);
        let mut by_name = HashMap::with_capacity(count as usize);
        let mut inflated = 0u64;
        let mut at = 0usize;
        for i in 0..count as usize {
            if cd.len() - at < CDH_LEN || &cd[at..at + 4] != CDH_SIG {
                return Err(unreadable(format!("zip entry {i}: no central directory header where it should start")));
            }
            let h = Fields(&cd[at..]);
            let (flags, method, crc) = (h.u16(8), h.u16(10), h.u32(16));
            let (mut compressed, mut size, mut local) = (u64::from(h.u32(20)), u64::from(h.u32(24)), u64::from(h.u32(42)));
            let (name_len, extra_len, comment_len) =
                (usize::from(h.u16(28)), usize::from(h.u16(30)), usize::from(h.u16(32)));
            let body = cd.len() - at - CDH_LEN;
            if body < name_len + extra_len + comment_len {
                return Err(unreadable(format!("zip entry {i}: its header runs past the central directory")));
            }
            let name = String::from_utf8_lossy(&cd[at + CDH_LEN..][..name_len]).into_owned();
            let extra = &cd[at + CDH_LEN + name_len..][..extra_len];
            zip64_extra(extra, [&mut size, &mut compressed, &mut local])
                .map_err(|why| unreadable(format!("zip entry {name}: {why}")))?;
            at += CDH_LEN + name_len + extra_len + comment_len;
            if flags & 1 != 0 {
                return Err(format!("zip entry {name} is encrypted"));
            }
            if method != 0 && method != 8 {
                return Err(format!(
                    "zip entry {name} is compressed with {}; checkpoints have stored or deflated entries only",
                    method_name(method)
                ));
            }
            if local >= cd_offset {
                return Err(unreadable(format!("zip entry {name} would start inside the central directory")));
            }
            inflated = inflated.saturating_add(size);
            by_name.insert(name.clone(), i);
            entries.push(Entry { name, method, crc, compressed, size, local });
        }
        if at != cd.len() {
            return Err(unreadable(format!(
                "its central directory holds more than the {count} entries its end record declares"
            )));
        }
        let limit = MAX_INFLATION.saturating_mul(len).saturating_add(INFLATION_SLACK);
        if inflated > limit {
            return Err(format!(
                "its zip entries would inflate to {inflated} bytes, more than {MAX_INFLATION} times its {len} bytes + \
                 {} MiB ({limit} bytes): refused (a decompression bomb?)",
                INFLATION_SLACK >> 20
            ));
        }
        let prefix = entries.first().and_then(|e| e.name.split_once('/')).map(|(top, _)| format!("{top}/"));
        let prefix = prefix.ok_or("a zip archive without the top folder torch.save writes (no data.pkl)")?;
        Ok(Archive { reader, entries, by_name, directory: cd_offset, prefix, inflated })
    }

    /// The full name of the record `name` (`data.pkl`, `data/0`) under the archive's top folder.
    pub fn record(&self, name: &str) -> String {
        format!("{}{name}", self.prefix)
    }

    fn entry(&self, name: &str) -> Result<&Entry, String> {
        let full = self.record(name);
        self.by_name.get(&full).map(|&i| &self.entries[i]).ok_or_else(|| format!("no zip entry {full}"))
    }

    /// Whether the record `name` exists.
    pub fn has(&self, name: &str) -> bool {
        self.entry(name).is_ok()
    }

    /// The declared size of the record `name`.
    pub fn size(&mut self, name: &str) -> Result<u64, String> {
        Ok(self.entry(name)?.size)
    }

    /// The bytes of the record `name`, which must be at most `max` bytes as declared, and inflate to exactly
    /// its declared size with the right CRC. Reads its local header and its data once.
    pub fn read(&mut self, name: &str, max: u64) -> Result<Vec<u8>, String> {
        let entry = self.entry(name)?.clone();
        let full = &entry.name;
        let declared = entry.size;
        if declared > max {
            return Err(format!("zip entry {full} is {declared} bytes, more than the {max} accepted"));
        }
        let damaged = |why: String| format!("zip entry {full}: {why} (a damaged archive?)");
        let header = read_at(&mut self.reader, entry.local, LOCAL_LEN).map_err(damaged)?;
        if &header[..4] != LOCAL_SIG {
            return Err(damaged("no local header where its directory entry says".into()));
        }
        let h = Fields(&header);
        let data = entry.local + (LOCAL_LEN + usize::from(h.u16(26)) + usize::from(h.u16(28))) as u64;
        if data.checked_add(entry.compressed).is_none_or(|end| end > self.directory) {
            return Err(damaged("its data would run into the central directory".into()));
        }
        self.reader.seek(SeekFrom::Start(data)).map_err(|e| damaged(e.to_string()))?;
        let raw = (&mut self.reader).take(entry.compressed);
        let mut bytes = Vec::with_capacity(declared as usize);
        // One byte past the declared size: an entry that inflates to more is caught without reading it all.
        let got = match entry.method {
            0 => raw.take(declared + 1).read_to_end(&mut bytes),
            _ => DeflateDecoder::new(raw).take(declared + 1).read_to_end(&mut bytes),
        };
        got.map_err(|e| damaged(e.to_string()))?;
        if bytes.len() as u64 != declared {
            return Err(format!(
                "zip entry {full} inflates to {}{} bytes, not its declared {declared}",
                bytes.len(),
                if bytes.len() as u64 > declared { " or more" } else { "" }
            ));
        }
        let mut crc = flate2::Crc::new();
        crc.update(&bytes);
        if crc.sum() != entry.crc {
            return Err(damaged(format!("its CRC is {:08x}, not the {:08x} declared", crc.sum(), entry.crc)));
        }
        Ok(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Cursor, Write};
    use zip::write::SimpleFileOptions;
    use zip::CompressionMethod;

    pub(crate) fn archive(entries: &[(&str, &[u8])], method: CompressionMethod) -> Vec<u8> {
        let mut writer = zip::ZipWriter::new(Cursor::new(Vec::new()));
        for (name, data) in entries {
            writer.start_file(*name, SimpleFileOptions::default().compression_method(method)).unwrap();
            writer.write_all(data).unwrap();
        }
        writer.finish().unwrap().into_inner()
    }

    fn open(bytes: &[u8]) -> Result<Archive<Cursor<&[u8]>>, String> {
        Archive::open(Cursor::new(bytes), bytes.len() as u64)
    }

    #[test]
    fn reads_records_under_the_top_folder() {
        for method in [CompressionMethod::Stored, CompressionMethod::Deflated] {
            let bytes = archive(&[("run/data.pkl", b"pickle"), ("run/data/0", &[7u8; 100])], method);
            let mut a = open(&bytes).unwrap();
            assert_eq!(a.read("data.pkl", 100).unwrap(), b"pickle");
            assert_eq!(a.read("data/0", 100).unwrap(), vec![7u8; 100]);
            assert!(a.has("data/0") && !a.has("data/1"));
            assert_eq!(a.inflated, 106);
            assert!(a.read("data/0", 99).unwrap_err().contains("more than the 99 accepted"));
            assert!(a.read("data/1", 99).unwrap_err().contains("no zip entry run/data/1"));
        }
    }

    #[test]
    fn bombs_prepended_data_and_damage_are_refused() {
        let zeros = vec![0u8; 80 << 20];
        let bomb = archive(&[("a/data.pkl", b"x"), ("a/data/0", &zeros)], CompressionMethod::Deflated);
        let err = open(&bomb).err().unwrap();
        assert!(err.contains(&format!("inflate to {} bytes", (80 << 20) + 1)) && err.contains("bomb"), "{err}");

        let good = archive(&[("a/data.pkl", b"x"), ("a/data/0", &[1u8; 64])], CompressionMethod::Stored);
        let mut prepended = good[..30].to_vec();
        prepended.extend_from_slice(&good);
        assert!(open(&prepended).err().unwrap().contains("data before its entries"));
        assert!(open(&good[..good.len() / 2]).err().unwrap().contains("not a readable zip archive"));
        // A flipped byte of stored data fails the CRC.
        let at = good.windows(4).position(|w| w == [1, 1, 1, 1]).unwrap();
        let mut flipped = good.clone();
        flipped[at] = 2;
        assert!(open(&flipped).unwrap().read("data/0", 64).unwrap_err().contains("a damaged archive"));
    }

    /// A reader that counts the bytes read through it.
    pub(crate) struct Counting<R> {
        pub inner: R,
        pub read: u64,
        pub seeks: u64,
    }

    impl<R: Read> Read for Counting<R> {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            let n = self.inner.read(buf)?;
            self.read += n as u64;
            Ok(n)
        }
    }

    impl<R: Seek> Seek for Counting<R> {
        fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
            self.seeks += 1;
            self.inner.seek(to)
        }
    }

    /// `bytes` with its end record's comment replaced by `comment` (its length fixed up, as the probe did).
    pub(crate) fn with_comment(bytes: &[u8], comment: &[u8]) -> Vec<u8> {
        let eocd = find_eocd(bytes).unwrap();
        let mut out = bytes[..eocd + 20].to_vec();
        out.extend_from_slice(&(comment.len() as u16).to_le_bytes());
        out.extend_from_slice(comment);
        out
    }

    /// A fake end record: one entry, its directory at `cd_offset` of 46 bytes, a comment of `comment_len` bytes.
    pub(crate) fn fake_eocd(cd_offset: u32, comment_len: u16) -> Vec<u8> {
        let mut r = EOCD_SIG.to_vec();
        r.extend_from_slice(&[0, 0, 0, 0, 1, 0, 1, 0]);
        r.extend_from_slice(&46u32.to_le_bytes());
        r.extend_from_slice(&cd_offset.to_le_bytes());
        r.extend_from_slice(&comment_len.to_le_bytes());
        r
    }

    /// Opens `bytes` through a counting reader and reads every entry: what it gives (or why not), and the
    /// bytes read, which must be at most the file's once, plus its tail and the local headers once more.
    fn read_all_counted(bytes: &[u8]) -> (Result<Vec<Vec<u8>>, String>, u64) {
        let mut reader = Counting { inner: Cursor::new(bytes), read: 0, seeks: 0 };
        let result = (|| {
            let mut a = Archive::open(&mut reader, bytes.len() as u64)?;
            let names: Vec<String> = a.entries.iter().map(|e| e.name.clone()).collect();
            let prefix = a.prefix.clone();
            names.iter().map(|n| a.read(n.strip_prefix(&prefix).unwrap(), u64::MAX)).collect()
        })();
        let bound = bytes.len() as u64 + MAX_TAIL as u64 + 1024;
        assert!(reader.read <= bound, "read {} bytes of a {}-byte file (bound {bound})", reader.read, bytes.len());
        assert!(reader.seeks <= 16, "{} seeks", reader.seeks);
        (result, reader.read)
    }

    #[test]
    fn a_comment_full_of_directory_records_is_read_once() {
        // Issue 50: a 64 KiB comment of end-record signatures (and of whole fake end records pointing at the
        // start of the file) made the zip library retry from each one, scanning the file every time.
        let good = archive(&[("a/data.pkl", b"pickle"), ("a/data/0", &[5u8; 4096])], CompressionMethod::Stored);
        let signatures = EOCD_SIG.repeat(65532 / 4);
        let records: Vec<u8> = (0..65535 / 22).flat_map(|_| fake_eocd(0, 1)).collect();
        let started = std::time::Instant::now();
        for comment in [&signatures, &records] {
            let planted = with_comment(&good, comment);
            let (entries, _) = read_all_counted(&planted);
            assert_eq!(entries.unwrap(), [b"pickle".to_vec(), vec![5u8; 4096]]);
        }
        // Fake records whose comment reaches the end: the last is taken (as the format says), and refused at once.
        let mut refused = records.clone();
        refused.extend_from_slice(&fake_eocd(0, 0));
        let (entries, _) = read_all_counted(&with_comment(&good, &refused));
        let err = entries.unwrap_err();
        assert!(err.contains("displaced central directory"), "{err}");
        // A comment past the 64 KiB the format allows, or one that does not reach the end: no record found.
        let mut long = with_comment(&good, &signatures);
        long.extend_from_slice(&[0u8; 100]);
        let err = read_all_counted(&long).0.unwrap_err();
        assert!(err.contains("no end-of-central-directory record"), "{err}");
        assert!(started.elapsed().as_secs() < 30, "a generous guard, not a timing: {:?}", started.elapsed());
    }

    #[test]
    fn fake_records_in_the_data_and_fake_local_headers_are_never_searched() {
        // An entry whose contents are thousands of fake end records, central directory headers and local headers:
        // read as the data it is.
        let mut cd_header = CDH_SIG.to_vec();
        cd_header.extend_from_slice(&[0u8; 42]);
        let mut local = LOCAL_SIG.to_vec();
        local.extend_from_slice(&[0u8; 26]);
        let mut planted = Vec::new();
        for i in 0..4000u32 {
            planted.extend_from_slice(&fake_eocd(i * 98, 0));
            planted.extend_from_slice(&cd_header);
            planted.extend_from_slice(&local);
        }
        for method in [CompressionMethod::Stored, CompressionMethod::Deflated] {
            let bytes = archive(&[("a/data.pkl", &planted), ("a/data/0", &planted[..1000])], method);
            let (entries, _) = read_all_counted(&bytes);
            assert_eq!(entries.unwrap(), [planted.clone(), planted[..1000].to_vec()]);
            // The same after the directory's end, in the comment (as much as fits).
            let comment = &planted[..65535];
            let (entries, _) = read_all_counted(&with_comment(&bytes, comment));
            assert_eq!(entries.unwrap()[1], planted[..1000]);
        }
    }

    #[test]
    fn counts_and_offsets_are_checked_against_what_was_read() {
        let good = archive(&[("a/data.pkl", b"x"), ("a/data/0", &[1u8; 64])], CompressionMethod::Stored);
        let eocd = find_eocd(&good).unwrap();
        let patched = |at: usize, value: &[u8]| {
            let mut b = good.clone();
            b[eocd + at..eocd + at + value.len()].copy_from_slice(value);
            read_all_counted(&b).0.unwrap_err()
        };
        // 65535 entries declared in a directory of two.
        assert!(patched(8, &[0xFF, 0xFF, 0xFF, 0xFF]).contains("65535 entries declared"));
        // One entry declared: the second header is left over.
        assert!(patched(8, &[1, 0, 1, 0]).contains("more than the 1 entries"));
        // A directory that would end past the end record.
        assert!(patched(12, &[0xFF, 0xFF, 0, 0]).contains("past its end record"));
        // Multi-disk.
        assert!(patched(4, &[1, 0]).contains("multi-disk"));
        // A local header offset past the data: its data would run into the directory.
        let cd = u32::from_le_bytes(good[eocd + 16..eocd + 20].try_into().unwrap()) as usize;
        let mut b = good.clone();
        let second = cd + CDH_LEN + "a/data.pkl".len();
        assert_eq!(&b[second..second + 4], CDH_SIG);
        b[second + 42..second + 46].copy_from_slice(&((cd - 10) as u32).to_le_bytes());
        let err = read_all_counted(&b).0.unwrap_err();
        assert!(err.contains("a damaged archive"), "{err}");
    }

    #[test]
    fn zip64_records_are_read_where_the_locator_says() {
        // The end records as Python's zipfile and PyTorch write them for large archives: a zip64 end record and
        // its locator before an end record whose fields are all ones; sizes and offsets in zip64 extra fields.
        let good = archive(&[("a/data.pkl", b"pickle"), ("a/data/0", &[3u8; 300])], CompressionMethod::Stored);
        let eocd = find_eocd(&good).unwrap();
        let f = Fields(&good[eocd..]);
        let (count, cd_offset) = (u64::from(f.u16(10)), u64::from(f.u32(16)));
        // The second header's size and offset moved into a zip64 extra field.
        let second = cd_offset as usize + CDH_LEN + "a/data.pkl".len();
        let mut bytes = good[..second].to_vec();
        let mut header = good[second..second + CDH_LEN].to_vec();
        let (size, local) = (Fields(&header).u32(24), Fields(&header).u32(42));
        header[24..28].copy_from_slice(&u32::MAX.to_le_bytes());
        header[42..46].copy_from_slice(&u32::MAX.to_le_bytes());
        header[30..32].copy_from_slice(&(4u16 + 4 + 16).to_le_bytes());
        bytes.extend_from_slice(&header);
        bytes.extend_from_slice(b"a/data/0");
        bytes.extend_from_slice(&[0x99, 0x99, 0, 0]); // another extra field first, empty
        bytes.extend_from_slice(&[1, 0, 16, 0]);
        bytes.extend_from_slice(&u64::from(size).to_le_bytes());
        bytes.extend_from_slice(&u64::from(local).to_le_bytes());
        // Only ones: the zip64 record holds the counts (extra bytes beyond the record, as the format allows).
        let cd_size = bytes.len() as u64 - cd_offset;
        let record_at = bytes.len() as u64;
        bytes.extend_from_slice(ZIP64_EOCD_SIG);
        bytes.extend_from_slice(&44u64.to_le_bytes());
        bytes.extend_from_slice(&[45, 0, 45, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
        for v in [count, count, cd_size, cd_offset] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        bytes.extend_from_slice(ZIP64_LOCATOR_SIG);
        bytes.extend_from_slice(&0u32.to_le_bytes());
        bytes.extend_from_slice(&record_at.to_le_bytes());
        bytes.extend_from_slice(&1u32.to_le_bytes());
        bytes.extend_from_slice(EOCD_SIG);
        bytes.extend_from_slice(&[0, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF]);
        bytes.extend_from_slice(&[0xFF; 8]);
        bytes.extend_from_slice(&[0, 0]);
        let (entries, _) = read_all_counted(&bytes);
        assert_eq!(entries.unwrap(), [b"pickle".to_vec(), vec![3u8; 300]]);
        // A locator pointing past itself, or at no record; an extra field running past the header.
        let mut b = bytes.clone();
        let locator = b.len() - EOCD_LEN - ZIP64_LOCATOR_LEN;
        b[locator + 8..locator + 16].copy_from_slice(&(locator as u64).to_le_bytes());
        assert!(read_all_counted(&b).0.unwrap_err().contains("overlap its locator"));
        b[locator + 8..locator + 16].copy_from_slice(&0u64.to_le_bytes());
        assert!(read_all_counted(&b).0.unwrap_err().contains("no zip64 end record"));
        let mut b = bytes.clone();
        b[second + CDH_LEN + 8 + 6] = 20; // the zip64 field claims 4 more bytes than the extra data holds
        assert!(read_all_counted(&b).0.unwrap_err().contains("extra field runs past"));
    }
}
