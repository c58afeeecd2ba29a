//! The zip archive of a `torch.save` checkpoint (PyTorch >= 1.6): entries under one top folder
//! (`archive/data.pkl`, `archive/data/N`, `archive/byteorder`, ...), stored or deflated. Everything is checked
//! from the central directory before an entry is read, as the Python converter checks it: the entries together
//! may inflate to at most [`MAX_INFLATION`] times the file's size + [`INFLATION_SLACK`] (a decompression bomb is
//! refused unread), no data may come before the first entry (PyTorch and the zip crate would then read different
//! entries), and an entry is read only up to its declared size, which it must match exactly (its CRC is checked).

use std::io::{Read, Seek};

use zip::{CompressionMethod, ZipArchive};

/// Entries may inflate to at most this many times the file's size ...
pub const MAX_INFLATION: u64 = 4;
/// ... plus this many bytes (torch.save stores entries uncompressed: its archives inflate by a factor of 1).
pub const INFLATION_SLACK: u64 = 64 << 20;

/// An opened, checked checkpoint archive.
pub struct Archive<R: Read + Seek> {
    zip: ZipArchive<R>,
    /// The top folder of the entries (`archive` for torch.save of PyTorch >= 2; older versions used the file's
    /// name), with its slash.
    prefix: String,
    /// The declared size of all entries: what the archive inflates to.
    pub inflated: u64,
}

impl<R: Read + Seek> Archive<R> {
    /// Opens the archive of `len` bytes in `reader` and checks its central directory.
    pub fn open(reader: R, len: u64) -> Result<Archive<R>, String> {
        let mut zip = ZipArchive::new(reader).map_err(|e| format!("not a readable zip archive ({e})"))?;
        if zip.offset() != 0 {
            return Err("a zip archive with data before its entries or a displaced central directory, not as \
                        torch.save writes it"
                .into());
        }
        let mut inflated = 0u64;
        let mut prefix = None;
        for i in 0..zip.len() {
            let entry = zip.by_index_raw(i).map_err(|e| format!("zip entry {i}: {e}"))?;
            if !matches!(entry.compression(), CompressionMethod::Stored | CompressionMethod::Deflated) {
                return Err(format!(
                    "zip entry {} is compressed with {}; checkpoints have stored or deflated entries only",
                    entry.name(),
                    entry.compression()
                ));
            }
            if entry.encrypted() {
                return Err(format!("zip entry {} is encrypted", entry.name()));
            }
            inflated = inflated.saturating_add(entry.size());
            if prefix.is_none() {
                prefix = entry.name().split_once('/').map(|(top, _)| format!("{top}/"));
            }
        }
        let limit = MAX_INFLATION * len + INFLATION_SLACK;
        if inflated > limit {
            return Err(format!(
                "its zip entries would inflate to {inflated} bytes, more than {MAX_INFLATION} times its {len} bytes + \
                 {} MiB ({limit} bytes): refused (a decompression bomb?)",
                INFLATION_SLACK >> 20
            ));
        }
        let prefix = prefix.ok_or("a zip archive without the top folder torch.save writes (no data.pkl)")?;
        Ok(Archive { zip, prefix, inflated })
    }

    /// The full name of the record `name` (`data.pkl`, `data/0`) under the archive's top folder.
    pub fn record(&self, name: &str) -> String {
        format!("{}{name}", self.prefix)
    }

    /// Whether the record `name` exists.
    pub fn has(&self, name: &str) -> bool {
        self.zip.index_for_name(&self.record(name)).is_some()
    }

    /// The declared size of the record `name`.
    pub fn size(&mut self, name: &str) -> Result<u64, String> {
        let full = self.record(name);
        let index = self.zip.index_for_name(&full).ok_or_else(|| format!("no zip entry {full}"))?;
        Ok(self.zip.by_index_raw(index).map_err(|e| format!("zip entry {full}: {e}"))?.size())
    }

    /// The bytes of the record `name`, which must be at most `max` bytes as declared, and inflate to exactly
    /// its declared size with the right CRC.
    pub fn read(&mut self, name: &str, max: u64) -> Result<Vec<u8>, String> {
        let full = self.record(name);
        let declared = self.size(name)?;
        if declared > max {
            return Err(format!("zip entry {full} is {declared} bytes, more than the {max} accepted"));
        }
        let index = self.zip.index_for_name(&full).expect("found by size()");
        let entry = self.zip.by_index(index).map_err(|e| format!("zip entry {full}: {e}"))?;
        let mut bytes = Vec::with_capacity(declared as usize);
        // One byte past the declared size: an entry that inflates to more is caught without reading it all.
        entry
            .take(declared + 1)
            .read_to_end(&mut bytes)
            .map_err(|e| format!("zip entry {full}: {e} (a damaged archive?)"))?;
        if bytes.len() as u64 != declared {
            return Err(format!(
                "zip entry {full} inflates to {}{} bytes, not its declared {declared}",
                bytes.len(),
                if bytes.len() as u64 > declared { " or more" } else { "" }
            ));
        }
        Ok(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Cursor, Write};
    use zip::write::SimpleFileOptions;

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
}
