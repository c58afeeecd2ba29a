#![no_main]
// See raypatch::fuzzing::frames_folder.
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    raypatch::fuzzing::frames_folder(data);
});
