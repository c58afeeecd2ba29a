//! A pickle interpreter that executes nothing: the opcodes `torch.save` and Lightning write (protocols 2 to 5)
//! become plain values in an arena. A global becomes its name, a call (`REDUCE`, `NEWOBJ`) the callable's name
//! and its arguments; the containers torch and Lightning rebuild through calls (`OrderedDict`, Lightning's
//! `AttributeDict`, `defaultdict`, `argparse.Namespace`) become dicts that later opcodes fill, and `torch.rs`
//! decodes the tensor rebuilds. Globals outside [`allowed`](super::globals::allowed) are refused by name, as the Python converter's
//! weights-only unpickler refuses them: such a pickle would run code when loaded by PyTorch.
//!
//! Hardening (the ideas of candle's `pickle.rs`, without its trust in the file): a length is checked against
//! the bytes that remain before anything is allocated for it; a memo entry is the index of a value, never a
//! copy of it, so a pickle of shared references costs its size, not their expansion; the stack, the memo and
//! every value count against [`MAX_MEMORY`]; values are traversed with a depth bound ([`MAX_DEPTH`], which also
//! stops cycles made through the memo). Reading the resulting values ([`Pickle::get`], [`Pickle::describe`], …)
//! is in `pickle/values.rs`.

mod values;

use std::collections::HashMap;

use super::globals::{allowed, dict_like};

/// The index of a value in [`Pickle::nodes`].
pub type Id = u32;

/// What the interpreter may allocate for one pickle (values, containers, stack and memo): a Lightning
/// checkpoint's pickle needs well under 1 MiB per 1,000 tensors.
pub const MAX_MEMORY: usize = 256 << 20;
/// The deepest nesting [`Pickle`]'s consumers follow (official checkpoints nest about 8 deep).
pub const MAX_DEPTH: usize = 64;
/// The most memo entries (official checkpoints use a few per tensor).
pub const MAX_MEMO: usize = 1 << 20;
/// The longest string or bytes value.
pub const MAX_STRING: usize = 16 << 20;

/// A value the pickle built.
#[derive(Debug, Clone, PartialEq)]
pub enum Node {
    None,
    Bool(bool),
    Int(i64),
    /// An integer beyond i64 (read, not kept).
    BigInt,
    Float(f64),
    Str(String),
    /// Bytes of this length (the model never needs their contents).
    Bytes(usize),
    List(Vec<Id>),
    Tuple(Vec<Id>),
    /// Items in insertion order; a later item with an equal key replaces an earlier one for readers.
    Dict(Vec<(Id, Id)>),
    Set(Vec<Id>),
    /// A global named, not imported: `module.name`.
    Global(String),
    /// `BINPERSID`: a reference to data outside the pickle (torch: a storage).
    Persistent(Id),
    /// A call not decoded: the callable (a [`Node::Global`]), its argument tuple, and the `BUILD` state.
    Call {
        callable: Id,
        args: Id,
        state: Option<Id>,
    },
}

/// The interpreted pickle: every value, and the one it returned.
#[derive(Debug)]
pub struct Pickle {
    pub nodes: Vec<Node>,
    pub root: Id,
}

/// Why a pickle is refused: one phrase, with the byte offset of the opcode where it applies.
#[derive(Debug, Clone, PartialEq)]
pub struct PickleError {
    pub offset: usize,
    pub reason: String,
}

impl std::fmt::Display for PickleError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} (at byte {})", self.reason, self.offset)
    }
}

enum Slot {
    Mark,
    Value(Id),
}

struct Machine<'a> {
    data: &'a [u8],
    at: usize,
    op_at: usize,
    nodes: Vec<Node>,
    stack: Vec<Slot>,
    memo: HashMap<u32, Id>,
    memory: usize,
}

/// Interprets `data`, a whole pickle, up to its `STOP`.
pub fn interpret(data: &[u8]) -> Result<Pickle, PickleError> {
    let mut m =
        Machine { data, at: 0, op_at: 0, nodes: Vec::new(), stack: Vec::new(), memo: HashMap::new(), memory: 0 };
    loop {
        m.op_at = m.at;
        let op = m.take(1)?[0];
        if op == b'.' {
            let root = m.pop()?;
            return Ok(Pickle { nodes: m.nodes, root });
        }
        m.step(op)?;
    }
}

impl<'a> Machine<'a> {
    fn err<T>(&self, reason: impl Into<String>) -> Result<T, PickleError> {
        Err(PickleError { offset: self.op_at, reason: reason.into() })
    }

    fn charge(&mut self, bytes: usize) -> Result<(), PickleError> {
        self.memory += bytes;
        if self.memory > MAX_MEMORY {
            return self.err(format!("its values need more than the {MAX_MEMORY} bytes a checkpoint's pickle may use"));
        }
        Ok(())
    }

    /// The next `n` bytes, checked against what remains before anything is made of them.
    fn take(&mut self, n: usize) -> Result<&'a [u8], PickleError> {
        if n > self.data.len() - self.at {
            return self.err(format!("needs {n} bytes, {} remain (truncated pickle?)", self.data.len() - self.at));
        }
        self.at += n;
        Ok(&self.data[self.at - n..self.at])
    }

    fn uint(&mut self, n: usize) -> Result<u64, PickleError> {
        Ok(self.take(n)?.iter().rev().fold(0u64, |v, &b| (v << 8) | u64::from(b)))
    }

    /// A length read from the file: bounded by [`MAX_STRING`] and by the bytes that remain.
    fn length(&mut self, n: usize) -> Result<usize, PickleError> {
        let len = self.uint(n)?;
        if len > MAX_STRING as u64 {
            return self.err(format!("a {len}-byte string or bytes value, more than the {MAX_STRING} accepted"));
        }
        Ok(len as usize)
    }

    fn line(&mut self) -> Result<String, PickleError> {
        let rest = &self.data[self.at..];
        let Some(end) = rest.iter().take(1024).position(|&b| b == b'\n') else {
            return self.err("a name without its newline in the first 1024 bytes");
        };
        let text = String::from_utf8_lossy(&rest[..end]).into_owned();
        self.at += end + 1;
        Ok(text)
    }

    fn push_node(&mut self, node: Node) -> Result<(), PickleError> {
        let id = self.add(node)?;
        self.push(id)
    }

    fn add(&mut self, node: Node) -> Result<Id, PickleError> {
        let payload = match &node {
            Node::Str(s) => s.len(),
            _ => 0,
        };
        self.charge(std::mem::size_of::<Node>() + payload)?;
        self.nodes.push(node);
        Ok((self.nodes.len() - 1) as Id)
    }

    fn push(&mut self, id: Id) -> Result<(), PickleError> {
        self.charge(std::mem::size_of::<Slot>())?;
        self.stack.push(Slot::Value(id));
        Ok(())
    }

    fn pop(&mut self) -> Result<Id, PickleError> {
        match self.stack.pop() {
            Some(Slot::Value(id)) => Ok(id),
            Some(Slot::Mark) => self.err("a value was expected on the stack, found a mark"),
            None => self.err("the stack is empty"),
        }
    }

    fn top(&self) -> Result<Id, PickleError> {
        match self.stack.last() {
            Some(Slot::Value(id)) => Ok(*id),
            _ => self.err("a value was expected on the stack"),
        }
    }

    /// The values above the topmost mark, which is removed.
    fn pop_mark(&mut self) -> Result<Vec<Id>, PickleError> {
        let Some(mark) = self.stack.iter().rposition(|s| matches!(s, Slot::Mark)) else {
            return self.err("no mark on the stack");
        };
        let items = self.stack.split_off(mark + 1);
        self.stack.pop();
        Ok(items
            .into_iter()
            .map(|s| if let Slot::Value(id) = s { id } else { unreachable!("marks end at the last") })
            .collect())
    }

    fn global(&mut self, module: &str, name: &str) -> Result<(), PickleError> {
        let full = format!("{module}.{name}");
        if !allowed(&full) {
            return self.err(format!(
                "refusing to unpickle {full}: not a tensor or a plain container/config object (unpickling it could run code)"
            ));
        }
        self.push_node(Node::Global(full))
    }

    /// A call of `callable` with `args`: an empty dict for the dict-like types, else a [`Node::Call`].
    fn call(&mut self, callable: Id, args: Id) -> Result<(), PickleError> {
        let node = match &self.nodes[callable as usize] {
            Node::Global(name) if dict_like(name) => Node::Dict(Vec::new()),
            Node::Global(_) => Node::Call { callable, args, state: None },
            other => return self.err(format!("a call of {}, which is not a global", kind(other))),
        };
        self.push_node(node)
    }

    fn memo_put(&mut self, key: u32) -> Result<(), PickleError> {
        let id = self.top()?;
        if self.memo.len() >= MAX_MEMO && !self.memo.contains_key(&key) {
            return self.err(format!("more than {MAX_MEMO} memo entries"));
        }
        self.charge(16)?;
        self.memo.insert(key, id);
        Ok(())
    }

    fn memo_get(&mut self, key: u32) -> Result<(), PickleError> {
        match self.memo.get(&key) {
            Some(&id) => self.push(id),
            None => self.err(format!("memo entry {key} is read before it is written")),
        }
    }

    /// Appends `items` to the list (or set) `target`; items given to an opaque object are dropped.
    fn extend(&mut self, target: Id, items: Vec<Id>) -> Result<(), PickleError> {
        self.charge(items.len() * std::mem::size_of::<Id>())?;
        match &mut self.nodes[target as usize] {
            Node::List(list) | Node::Set(list) => list.extend(items),
            Node::Call { .. } => {}
            other => {
                let what = format!("items appended to {}", kind(other));
                return self.err(what);
            }
        }
        Ok(())
    }

    fn set_items(&mut self, target: Id, items: Vec<Id>) -> Result<(), PickleError> {
        if items.len() % 2 != 0 {
            return self.err("SETITEMS with an odd number of values");
        }
        self.charge(items.len() * std::mem::size_of::<Id>())?;
        match &mut self.nodes[target as usize] {
            Node::Dict(dict) => dict.extend(items.chunks_exact(2).map(|kv| (kv[0], kv[1]))),
            Node::Call { .. } => {}
            other => {
                let what = format!("items set on {}", kind(other));
                return self.err(what);
            }
        }
        Ok(())
    }

    /// `BUILD`: a dict's state is its attributes (an OrderedDict's `_metadata`), except a Namespace-like dict
    /// made empty by its call, whose attributes are its items; a call keeps its state.
    fn build(&mut self, target: Id, state: Id) -> Result<(), PickleError> {
        // The state's items are copied only into an empty dict, and charged: a copy for every BUILD, whatever its
        // target, would let a pickle of shared references cost the product of its size and a dict's length.
        let empty = matches!(&self.nodes[target as usize], Node::Dict(items) if items.is_empty());
        if let (true, Node::Dict(state_items)) = (empty, &self.nodes[state as usize]) {
            let state_items = state_items.clone();
            self.charge(state_items.len() * 8)?;
            self.nodes[target as usize] = Node::Dict(state_items);
            return Ok(());
        }
        match &mut self.nodes[target as usize] {
            Node::Dict(_) => {}
            Node::Call { state: slot, .. } => *slot = Some(state),
            other => {
                let what = format!("BUILD on {}", kind(other));
                return self.err(what);
            }
        }
        Ok(())
    }

    fn step(&mut self, op: u8) -> Result<(), PickleError> {
        match op {
            0x80 => {
                let protocol = self.take(1)?[0];
                if !(2..=5).contains(&protocol) {
                    return self.err(format!("pickle protocol {protocol}, expected 2 to 5"));
                }
            }
            0x95 => {
                self.take(8)?; // FRAME: a length hint only
            }
            b'}' => self.push_node(Node::Dict(Vec::new()))?,
            b']' => self.push_node(Node::List(Vec::new()))?,
            b')' => self.push_node(Node::Tuple(Vec::new()))?,
            0x8f => self.push_node(Node::Set(Vec::new()))?,
            b'(' => {
                self.charge(std::mem::size_of::<Slot>())?;
                self.stack.push(Slot::Mark);
            }
            b'0' => {
                self.stack.pop().map_or_else(|| self.err("POP on an empty stack"), |_| Ok(()))?;
            }
            b'1' => {
                self.pop_mark()?;
            }
            b'2' => self.push(self.top()?)?,
            b'X' | 0x8c | 0x8d => {
                let n = self.length(match op {
                    b'X' => 4,
                    0x8c => 1,
                    _ => 8,
                })?;
                let bytes = self.take(n)?;
                let Ok(text) = std::str::from_utf8(bytes).map(str::to_owned) else {
                    return self.err("a string that is not UTF-8");
                };
                self.push_node(Node::Str(text))?;
            }
            b'T' | b'U' => {
                // Python 2 strings (protocol 2 from Python 2), read as Latin-1 text.
                let n = self.length(if op == b'T' { 4 } else { 1 })?;
                let text = self.take(n)?.iter().map(|&b| char::from(b)).collect();
                self.push_node(Node::Str(text))?;
            }
            b'B' | b'C' | 0x8e | 0x96 => {
                let n = self.length(match op {
                    b'B' => 4,
                    b'C' => 1,
                    _ => 8,
                })?;
                self.take(n)?;
                self.push_node(Node::Bytes(n))?;
            }
            b'J' => {
                let v = self.uint(4)? as u32 as i32;
                self.push_node(Node::Int(i64::from(v)))?;
            }
            b'K' => {
                let v = self.uint(1)?;
                self.push_node(Node::Int(v as i64))?;
            }
            b'M' => {
                let v = self.uint(2)?;
                self.push_node(Node::Int(v as i64))?;
            }
            0x8a | 0x8b => {
                let n = if op == 0x8a { self.uint(1)? as usize } else { self.length(4)? };
                let bytes = self.take(n)?;
                self.push_node(long(bytes))?;
            }
            b'G' => {
                let v = f64::from_bits(u64::from_be_bytes(self.take(8)?.try_into().expect("8 bytes")));
                self.push_node(Node::Float(v))?;
            }
            b'N' => self.push_node(Node::None)?,
            0x88 => self.push_node(Node::Bool(true))?,
            0x89 => self.push_node(Node::Bool(false))?,
            b't' => {
                let items = self.pop_mark()?;
                self.charge(items.len() * 4)?;
                self.push_node(Node::Tuple(items))?;
            }
            0x85..=0x87 => {
                let n = usize::from(op - 0x84);
                let mut items: Vec<Id> = (0..n).map(|_| self.pop()).collect::<Result<_, _>>()?;
                items.reverse();
                self.push_node(Node::Tuple(items))?;
            }
            b'l' => {
                let items = self.pop_mark()?;
                self.charge(items.len() * 4)?;
                self.push_node(Node::List(items))?;
            }
            b'a' => {
                let item = self.pop()?;
                let list = self.top()?;
                self.extend(list, vec![item])?;
            }
            b'e' | 0x90 => {
                let items = self.pop_mark()?;
                let list = self.top()?;
                self.extend(list, items)?;
            }
            0x91 => {
                let items = self.pop_mark()?;
                self.charge(items.len() * 4)?;
                self.push_node(Node::Set(items))?;
            }
            b'd' => {
                let items = self.pop_mark()?;
                let dict = self.add(Node::Dict(Vec::new()))?;
                self.set_items(dict, items)?;
                self.push(dict)?;
            }
            b's' => {
                let value = self.pop()?;
                let key = self.pop()?;
                let dict = self.top()?;
                self.set_items(dict, vec![key, value])?;
            }
            b'u' => {
                let items = self.pop_mark()?;
                let dict = self.top()?;
                self.set_items(dict, items)?;
            }
            b'q' | b'r' => {
                let key = self.uint(if op == b'q' { 1 } else { 4 })? as u32;
                self.memo_put(key)?;
            }
            0x94 => {
                let key = self.memo.len() as u32;
                self.memo_put(key)?;
            }
            b'h' | b'j' => {
                let key = self.uint(if op == b'h' { 1 } else { 4 })? as u32;
                self.memo_get(key)?;
            }
            b'c' => {
                let module = self.line()?;
                let name = self.line()?;
                self.global(&module, &name)?;
            }
            0x93 => {
                let name = self.pop()?;
                let module = self.pop()?;
                let (Node::Str(module), Node::Str(name)) = (&self.nodes[module as usize], &self.nodes[name as usize])
                else {
                    return self.err("STACK_GLOBAL of values that are not strings");
                };
                let (module, name) = (module.clone(), name.clone());
                self.global(&module, &name)?;
            }
            b'R' | 0x81 => {
                let args = self.pop()?;
                let callable = self.pop()?;
                self.call(callable, args)?;
            }
            0x92 => {
                let _kwargs = self.pop()?;
                let args = self.pop()?;
                let callable = self.pop()?;
                self.call(callable, args)?;
            }
            b'b' => {
                let state = self.pop()?;
                let target = self.top()?;
                self.build(target, state)?;
            }
            b'Q' => {
                let pid = self.pop()?;
                self.push_node(Node::Persistent(pid))?;
            }
            other => {
                let what = match other {
                    b'I' | b'L' | b'F' | b'S' | b'V' | b'P' | b'p' | b'g' | b'i' | b'o' => "a text-protocol opcode",
                    0x97 | 0x98 => "an out-of-band buffer",
                    _ => "an unknown opcode",
                };
                return self.err(format!("opcode 0x{other:02x}: {what}, not written by torch.save"));
            }
        }
        Ok(())
    }
}

/// A little-endian two's-complement integer of `LONG1`/`LONG4`.
fn long(bytes: &[u8]) -> Node {
    if bytes.len() > 8 {
        return Node::BigInt;
    }
    let negative = bytes.last().is_some_and(|&b| b & 0x80 != 0);
    let mut word = [if negative { 0xff } else { 0 }; 8];
    word[..bytes.len()].copy_from_slice(bytes);
    Node::Int(i64::from_le_bytes(word))
}

/// A string as messages quote it: in quotes, escaped, only its first 80 characters when it is longer.
pub fn quoted(s: &str) -> String {
    const MAX_CHARS: usize = 80;
    let count = s.chars().count();
    if count <= MAX_CHARS {
        return format!("{s:?}");
    }
    format!("{:?}... ({count} characters)", s.chars().take(MAX_CHARS).collect::<String>())
}

/// A value's kind in words, as messages name it (Python's names).
pub fn kind(node: &Node) -> String {
    match node {
        Node::None => "None".into(),
        Node::Bool(_) => "bool".into(),
        Node::Int(_) | Node::BigInt => "int".into(),
        Node::Float(_) => "float".into(),
        Node::Str(_) => "str".into(),
        Node::Bytes(_) => "bytes".into(),
        Node::List(_) => "list".into(),
        Node::Tuple(_) => "tuple".into(),
        Node::Dict(_) => "dict".into(),
        Node::Set(_) => "set".into(),
        Node::Global(name) => format!("the name {name}"),
        Node::Persistent(_) => "a persistent reference".into(),
        Node::Call { .. } => "an object".into(),
    }
}
