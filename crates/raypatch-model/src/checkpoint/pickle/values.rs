//! Reading the values an interpreted [`Pickle`] holds: a dict's items and keys, strings, ints, sequences, the
//! global a call calls, and a value described as messages quote it. The interpreter itself is `pickle.rs`.

use std::collections::HashMap;

use super::{kind, quoted, Id, Node, Pickle};

impl Pickle {
    pub fn node(&self, id: Id) -> &Node {
        &self.nodes[id as usize]
    }

    /// The items of the dict `id` as (key, value), a later equal string key replacing an earlier one in place.
    pub fn dict_items(&self, id: Id) -> Option<Vec<(Id, Id)>> {
        let Node::Dict(items) = self.node(id) else { return None };
        let mut out: Vec<(Id, Id)> = Vec::with_capacity(items.len());
        let mut seen: HashMap<&str, usize> = HashMap::new();
        for &(k, v) in items {
            match self.node(k) {
                Node::Str(key) => match seen.get(key.as_str()) {
                    Some(&at) => out[at].1 = v,
                    None => {
                        seen.insert(key, out.len());
                        out.push((k, v));
                    }
                },
                _ => out.push((k, v)),
            }
        }
        Some(out)
    }

    /// The value under the string key `key` of the dict `id`.
    pub fn get(&self, id: Id, key: &str) -> Option<Id> {
        let Node::Dict(items) = self.node(id) else { return None };
        items.iter().rev().find(|&&(k, _)| matches!(self.node(k), Node::Str(s) if s == key)).map(|&(_, v)| v)
    }

    pub fn str(&self, id: Id) -> Option<&str> {
        match self.node(id) {
            Node::Str(s) => Some(s),
            _ => None,
        }
    }

    pub fn int(&self, id: Id) -> Option<i64> {
        match self.node(id) {
            Node::Int(v) => Some(*v),
            _ => None,
        }
    }

    /// The items of a tuple or list.
    pub fn items(&self, id: Id) -> Option<&[Id]> {
        match self.node(id) {
            Node::Tuple(items) | Node::List(items) => Some(items),
            _ => None,
        }
    }

    /// The name of the global a call calls, if `id` is a call.
    pub fn call_of(&self, id: Id) -> Option<(&str, Id)> {
        match self.node(id) {
            Node::Call { callable, args, .. } => match self.node(*callable) {
                Node::Global(name) => Some((name, *args)),
                _ => None,
            },
            _ => None,
        }
    }

    /// A value as a message quotes it: short values whole, containers by kind and length.
    pub fn describe(&self, id: Id) -> String {
        match self.node(id) {
            Node::Int(v) => format!("int {v}"),
            Node::Float(v) => format!("float {v}"),
            Node::Bool(v) => format!("bool {}", if *v { "True" } else { "False" }),
            Node::Str(s) => format!("str {}", quoted(s)),
            Node::List(items) | Node::Tuple(items) | Node::Set(items) => {
                format!("{} of {} items", kind(self.node(id)), items.len())
            }
            Node::Dict(items) => format!("dict of {} items", items.len()),
            Node::Call { .. } => match self.call_of(id) {
                Some((name, _)) => format!("an object made by {name}"),
                None => "an object".into(),
            },
            other => kind(other),
        }
    }
}
