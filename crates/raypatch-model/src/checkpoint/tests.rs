//! The checkpoint reader on small hand-made pickles and archives: what torch.save writes is read, and hostile
//! pickles are refused by a bound, never by running out of memory or time.

use std::collections::BTreeMap;
use std::io::{Cursor, Write};

use zip::write::SimpleFileOptions;

use super::pickle::{interpret, Node};
use super::{convert, parse_if_checkpoint};

/// Writes pickle opcodes as `torch.save` (protocol 2) does.
#[derive(Default)]
struct P(Vec<u8>);

impl P {
    fn new() -> P {
        P(vec![0x80, 2])
    }
    fn op(mut self, op: u8) -> P {
        self.0.push(op);
        self
    }
    fn s(mut self, text: &str) -> P {
        self.0.push(b'X');
        self.0.extend_from_slice(&(text.len() as u32).to_le_bytes());
        self.0.extend_from_slice(text.as_bytes());
        self
    }
    fn int(mut self, v: i32) -> P {
        self.0.push(b'J');
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn float(mut self, v: f64) -> P {
        self.0.push(b'G');
        self.0.extend_from_slice(&v.to_be_bytes());
        self
    }
    fn global(mut self, module: &str, name: &str) -> P {
        self.0.push(b'c');
        self.0.extend_from_slice(format!("{module}\n{name}\n").as_bytes());
        self
    }
    fn put(self, key: u8) -> P {
        self.op(b'q').op(key)
    }
    fn get(self, key: u8) -> P {
        self.op(b'h').op(key)
    }
    fn bytes(self) -> Vec<u8> {
        self.op(b'.').0
    }

    /// `_rebuild_tensor_v2(storage KEY of `numel` elements of `storage`, offset, size, stride, False, OrderedDict())`.
    fn tensor(self, storage: &str, key: &str, numel: i32, offset: i32, size: &[i32], stride: &[i32]) -> P {
        let mut p = self.global("torch._utils", "_rebuild_tensor_v2").op(b'(');
        p = p.op(b'(').s("storage").global("torch", storage).s(key).s("cpu").int(numel).op(b't').op(b'Q');
        p = p.int(offset).op(b'(');
        for &d in size {
            p = p.int(d);
        }
        p = p.op(b't').op(b'(');
        for &s in stride {
            p = p.int(s);
        }
        p.op(b't').op(0x89).global("collections", "OrderedDict").op(b')').op(b'R').op(b't').op(b'R')
    }
}

/// A torch.save-like archive: `archive/data.pkl`, `archive/byteorder` and the storages `archive/data/KEY`.
fn archive(pickle: &[u8], storages: &[(&str, Vec<u8>)]) -> Vec<u8> {
    let mut w = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let stored = SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let mut entries =
        vec![("archive/data.pkl".to_string(), pickle.to_vec()), ("archive/byteorder".into(), b"little".to_vec())];
    entries.extend(storages.iter().map(|(key, data)| (format!("archive/data/{key}"), data.clone())));
    for (name, data) in entries {
        w.start_file(name, stored).unwrap();
        w.write_all(&data).unwrap();
    }
    w.finish().unwrap().into_inner()
}

/// A checkpoint dict: {"state_dict": OrderedDict(entries), "hyper_parameters": {"cfg": {"base": "srt", "x": [...]}}}.
fn checkpoint(entries: impl FnOnce(P) -> P) -> Vec<u8> {
    let p = P::new().op(b'}').put(0).op(b'(').s("state_dict").global("collections", "OrderedDict").op(b')').op(b'R');
    let p = entries(p.put(1).op(b'(')).op(b'u');
    let p = p.s("hyper_parameters").op(b'}').s("cfg").op(b'}').op(b'(').s("base").s("srt").s("x");
    let p = p.op(b'(').int(1).float(2.5).op(0x88).op(b'N').float(1e-5).op(b'l').op(b'u').op(b's');
    p.op(b'u').bytes()
}

fn f16_bits(values: &[u16]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn converted(bytes: &[u8]) -> Result<crate::TensorFile, String> {
    let file = convert(Cursor::new(bytes), bytes.len() as u64, "run.ckpt")?;
    crate::TensorFile::from_bytes("run.ckpt", file).map_err(|e| e.to_string())
}

#[test]
fn what_torch_save_writes_is_read() {
    // Halves 0..6; a transposed 2x2 view at offset 1: [[s1, s3], [s2, s4]].
    let halves = f16_bits(&[0x0000, 0x3c00, 0x4000, 0x4200, 0x4400, 0x4500]);
    let doubles: Vec<u8> = [0.1f64, -3.0].iter().flat_map(|v| v.to_le_bytes()).collect();
    let bf16 = f16_bits(&[0x3f80, 0xc000]); // 1.0, -2.0
    let pickle = checkpoint(|p| {
        p.s("encoder.w")
            .tensor("HalfStorage", "0", 6, 1, &[2, 2], &[1, 2])
            .s("encoder.d")
            .tensor("DoubleStorage", "1", 2, 0, &[2], &[1])
            .s("decoder_rp.b")
            .tensor("BFloat16Storage", "2", 2, 1, &[], &[])
            .s("encoder.bn.num_batches_tracked")
            .tensor("LongStorage", "3", 1, 0, &[], &[])
            .s("loss.w")
            .int(3)
    });
    let bytes = archive(&pickle, &[("0", halves), ("1", doubles), ("2", bf16), ("3", vec![0; 8])]);
    let file = converted(&bytes).unwrap();
    assert_eq!(file.keys().collect::<Vec<_>>(), ["decoder_rp.b", "encoder.d", "encoder.w"]);
    assert_eq!(file.f32("encoder.w").unwrap().data, [1.0, 3.0, 2.0, 4.0]);
    assert_eq!(file.f32("encoder.d").unwrap().data, [0.1f64 as f32, -3.0]);
    let scalar = file.f32("decoder_rp.b").unwrap();
    assert_eq!((scalar.shape.as_slice(), scalar.data.as_slice()), (&[][..], &[-2.0f32][..]));
    // The metadata as the Python converter writes it: json.dumps of the model section, in its order.
    let expected: BTreeMap<_, _> = [
        ("config", r#"{"base": "srt", "x": [1, 2.5, true, null, 1e-05]}"#),
        ("format", "raypatch-model/1"),
        ("source", "run.ckpt"),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    assert_eq!(file.metadata.clone().into_iter().collect::<BTreeMap<_, _>>(), expected);
    // Told apart by content: a safetensors file is not a checkpoint.
    assert!(parse_if_checkpoint("m.safetensors", &[8, 0, 0, 0, 0, 0, 0, 0, b'{', b'}']).unwrap().is_none());
    assert!(parse_if_checkpoint("anything.bin", &bytes).unwrap().is_some());
}

fn refusal(pickle: &[u8], storages: &[(&str, Vec<u8>)]) -> String {
    converted(&archive(pickle, storages)).err().expect("refused")
}

#[test]
fn bad_entries_are_named() {
    let cases: [(fn(P) -> P, &str); 6] = [
        (|p| p.s("encoder.x").int(3), "state_dict entry \"encoder.x\" is not a tensor but int 3"),
        (|p| p.int(3).tensor("FloatStorage", "0", 4, 0, &[4], &[1]), "state_dict key int 3 is not a string"),
        (|p| p.s("encoder.i").tensor("LongStorage", "0", 4, 0, &[4], &[1]), "has dtype torch.int64"),
        (|p| p.s("encoder.v").tensor("FloatStorage", "0", 4, 1, &[2, 2], &[2, 1]), "outside its 4-element storage"),
        (|p| p.s("encoder.e").tensor("FloatStorage", "0", 1, 0, &[1_000_000], &[0]), "expanded or overlapping"),
        (|p| p.s("encoder.m").tensor("FloatStorage", "9", 4, 0, &[4], &[1]), "no zip entry archive/data/9"),
    ];
    for (entries, fragment) in cases {
        let err = refusal(&checkpoint(entries), &[("0", vec![0; 16])]);
        assert!(err.contains(fragment), "{err}");
    }
    let err =
        refusal(&checkpoint(|p| p.s("encoder.s").tensor("FloatStorage", "0", 8, 0, &[8], &[1])), &[("0", vec![0; 16])]);
    assert!(err.contains("storage data/0 is 16 bytes") || err.contains("inflates to 16 bytes"), "{err}");
}

#[test]
fn code_is_never_run_and_globals_are_refused_by_name() {
    let evil = P::new().global("posix", "system").op(b'(').s("touch /tmp/x").op(b't').op(b'R').bytes();
    let err = interpret(&evil).unwrap_err().to_string();
    assert!(err.starts_with("refusing to unpickle posix.system: ") && err.contains("could run code"), "{err}");
    let stacked = P::new().s("builtins").s("exec").op(0x93).bytes();
    assert!(interpret(&stacked).unwrap_err().reason.contains("builtins.exec"));
    // Allowed globals that are not decoded stay values: a set, a torch.device.
    let device = P::new().global("torch", "device").op(b'(').s("cuda").op(b't').op(b'R').bytes();
    let p = interpret(&device).unwrap();
    assert_eq!(p.call_of(p.root).map(|(name, _)| name), Some("torch.device"));
}

#[test]
fn hostile_pickles_hit_a_bound() {
    let cases: Vec<(Vec<u8>, &str)> = vec![
        // A 4 GB string declared in a few bytes: refused before anything is allocated.
        (
            {
                let mut b = vec![0x80, 2, b'X'];
                b.extend_from_slice(&u32::MAX.to_le_bytes());
                b
            },
            "more than the",
        ),
        (
            {
                let mut b = vec![0x80, 2, b'X'];
                b.extend_from_slice(&1000u32.to_le_bytes());
                b
            },
            "truncated pickle",
        ),
        (vec![0x80, 2, 0x8b, 0xff, 0xff, 0xff, 0x7f], "more than the"),
        (vec![0x80, 2, b'h', 7, b'.'], "memo entry 7 is read before it is written"),
        (vec![0x80, 2, b'a', b'.'], "the stack is empty"),
        (vec![0x80, 2, b'I', b'1', b'\n', b'.'], "text-protocol opcode"),
        (vec![0x80, 1, b'.'], "pickle protocol 1"),
        (vec![0x80, 2, 0xfe, b'.'], "unknown opcode"),
        (vec![0x80, 2, b'N', b'N', b'u', b'.'], "no mark"),
    ];
    for (bytes, fragment) in cases {
        let err = interpret(&bytes).unwrap_err().to_string();
        assert!(err.contains(fragment), "{fragment}: {err}");
    }
    // Billion laughs: each list holds the previous one 10 times, 40 levels (10^40 leaves if copied). Memo
    // entries share, so it costs its bytes; a config made of it is refused by its value count.
    let mut p = P::new().op(b']').put(0).op(b'0');
    for level in 0..40u8 {
        p = p.op(b'(');
        for _ in 0..10 {
            p = p.get(level);
        }
        p = p.op(b'l').put(level + 1).op(b'0');
    }
    let laughs = p.get(40).bytes();
    let pickle = interpret(&laughs).unwrap();
    assert!(pickle.nodes.len() < 100, "{}", pickle.nodes.len());
    let mut cfg = P::new().op(b'}').s("hyper_parameters").op(b'}').s("cfg").op(b'}').s("base").s("srt").op(b's').s("x");
    cfg.0.extend_from_slice(&laughs[2..laughs.len()]);
    cfg.0.pop(); // the STOP
    let cfg = cfg.op(b's').op(b's').op(b's').bytes();
    let err = super::torch::model_config(&interpret(&cfg).unwrap()).unwrap_err();
    assert!(err.contains("more than 100000 values"), "{err}");
    // Issue 50: BUILD copied its state's items whatever its target, so a dict of n items given to n objects by
    // memo reads cost n^2 (here 4e10 copies); now linear. A generous guard, not a timing.
    let started = std::time::Instant::now();
    let mut p = P::new().global("torch._utils", "_rebuild_tensor_v2").op(b')').op(b'R');
    p = p.op(b'}').put(0).op(b'(');
    for _ in 0..200_000 {
        p = p.op(b'N').op(b'N');
    }
    p = p.op(b'u').op(b'0');
    for _ in 0..200_000 {
        p = p.get(0).op(b'b');
    }
    assert!(interpret(&p.bytes()).is_ok());
    assert!(started.elapsed().as_secs() < 30, "{:?}", started.elapsed());
    // A tensor of a million axes (all 1: one element) is refused before its axes are walked.
    let axes = vec![1; 1_000_000];
    let err = refusal(&checkpoint(|p| p.s("encoder.w").tensor("FloatStorage", "0", 1, 0, &axes, &axes)), &[("0", vec![0; 4])]);
    assert!(err.contains("1000000 dimensions, more than the 64 read"), "{err}");
    // Nesting: a config 100 lists deep.
    let mut deep =
        P::new().op(b'}').s("hyper_parameters").op(b'}').s("cfg").op(b'}').s("base").s("srt").op(b's').s("x");
    for _ in 0..100 {
        deep = deep.op(b']');
    }
    for _ in 0..99 {
        deep = deep.op(b'a');
    }
    let deep = deep.op(b's').op(b's').op(b's').bytes();
    let err = super::torch::model_config(&interpret(&deep).unwrap()).unwrap_err();
    assert!(err.contains("nested more than 64 levels deep"), "{err}");
}

#[test]
fn configs_are_found_or_named_missing() {
    let no_model = P::new().op(b'}').s("state_dict").op(b'}').op(b's').s("hyper_parameters").op(b'}').op(b's').bytes();
    let err = refusal(&no_model, &[]);
    assert!(err.contains("no model section in hyper_parameters[\"cfg\"]"), "{err}");
    let no_state = P::new().op(b'}').bytes();
    assert!(refusal(&no_state, &[]).contains("no state_dict (not a Lightning checkpoint?)"));
    let nan = P::new().op(b'}').s("hyper_parameters").op(b'}').s("cfg").op(b'}').s("base").s("srt").op(b's');
    let nan = nan.s("lr").float(f64::NAN);
    let nan = nan.op(b's').op(b's').op(b's').bytes();
    let err = super::torch::model_config(&interpret(&nan).unwrap()).unwrap_err();
    assert_eq!(err, "config value lr is nan, not a finite number");
    assert!(matches!(interpret(&P::new().op(b'N').bytes()).unwrap().nodes[0], Node::None));
}
