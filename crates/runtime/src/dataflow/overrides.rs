//! `--set NODE.KEY[.SUBKEY...]=VALUE`: command-line overrides of node configs, applied to the
//! parsed file before validation.
//!
//! The override is written into the located tree of the file, so the rest of the file keeps its
//! `file:line:column` diagnostics; the values it brings carry a marker location
//! ([`Override::loc`]) so that a config check refusing them names the override instead. The
//! effective dataflow text (run folder, recording) is the tree written back out
//! ([`crate::yaml::emit`]): it holds the effective values but not the file's comments.

use std::fmt;

use crate::yaml::{self, Loc, Node};

/// One `--set NODE.KEY[.SUBKEY...]=VALUE`: sets the key path in node NODE's `config:`, creating
/// missing mappings; VALUE is read as YAML (`house:3` a string, `320` a number, `{a: 1}` a
/// mapping).
#[derive(Debug, Clone, PartialEq)]
pub struct Override {
    text: String,
    path: String,
    value: Node,
}

impl Override {
    /// Parse `NODE.KEY[.SUBKEY...]=VALUE`; the error names the override.
    pub fn parse(text: &str) -> Result<Self, String> {
        let bad = |why: String| format!("`--set {text}`: {why}");
        let Some((path, value)) = text.split_once('=') else {
            return Err(bad("expected NODE.KEY=VALUE (no `=`)".into()));
        };
        let segments: Vec<&str> = path.split('.').collect();
        if segments.len() < 2 || segments.iter().any(|s| s.trim().is_empty()) {
            return Err(bad(format!(
                "`{path}` is not NODE.KEY[.SUBKEY...] (a node id, then config keys, separated by dots)"
            )));
        }
        let value = if value.trim().is_empty() {
            Node::Scalar {
                value: String::new(),
                quoted: false,
                loc: Loc::default(),
            }
        } else {
            yaml::parse(value)
                .map_err(|e| bad(format!("the value is not valid YAML: {}", e.message)))?
        };
        Ok(Self {
            text: text.to_string(),
            path: path.to_string(),
            value,
        })
    }

    /// The override as written, `NODE.KEY=VALUE`.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The marker location of the values brought by the `index`-th override (0-based): line 0,
    /// which no file has, and column `index + 1`.
    pub fn loc(index: usize) -> Loc {
        Loc {
            line: 0,
            col: index + 1,
        }
    }

    /// Index of the override a marker location of [`Override::loc`] stands for.
    pub fn index_of(loc: Loc) -> Option<usize> {
        (loc.line == 0 && loc.col > 0).then(|| loc.col - 1)
    }

    /// How the override is shown in messages and headers: `--set TEXT`, shell-quoted if needed.
    pub fn label(&self) -> String {
        let plain = self
            .text
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "_-./:=,@+%".contains(c));
        if plain {
            format!("--set {}", self.text)
        } else {
            format!("--set '{}'", self.text.replace('\'', r"'\''"))
        }
    }

    /// Write the override into the dataflow tree `root` as the `index`-th override; returns the
    /// id of the node it changed.
    pub fn apply(&self, root: &mut Node, index: usize) -> Result<String, String> {
        let loc = Self::loc(index);
        let bad = |why: String| format!("{}: {why}", self.label());
        let nodes: &mut [Node] = match root {
            Node::Map { entries, .. } => match entries.iter_mut().find(|e| e.0 == "nodes") {
                Some((_, _, Node::Seq { items, .. })) => items,
                _ => &mut [],
            },
            _ => &mut [],
        };
        let ids: Vec<String> = nodes
            .iter()
            .filter_map(|n| n.get("id").and_then(Node::as_str).map(str::to_string))
            .collect();
        // Node ids may hold dots: the longest id the path starts with wins.
        let Some((at, id)) = ids
            .iter()
            .enumerate()
            .filter(|(_, id)| {
                self.path
                    .strip_prefix(id.as_str())
                    .is_some_and(|rest| rest.len() > 1 && rest.starts_with('.'))
            })
            .max_by_key(|(_, id)| id.len())
        else {
            let wanted = self.path.split('.').next().unwrap_or_default();
            let known = if ids.is_empty() {
                "the file declares none".to_string()
            } else {
                ids.join(", ")
            };
            return Err(bad(format!("no node `{wanted}` (nodes: {known})")));
        };
        let keys: Vec<&str> = self.path[id.len() + 1..].split('.').collect();
        let node = nodes
            .iter_mut()
            .filter(|n| n.get("id").and_then(Node::as_str).is_some())
            .nth(at)
            .expect("the node the id came from");
        let mut here = node;
        for (depth, key) in std::iter::once("config")
            .chain(keys.iter().copied())
            .enumerate()
        {
            let Node::Map { entries, .. } = here else {
                let what = match depth {
                    0 => format!("node `{id}`"),
                    1 => format!("the `config` of node `{id}`"),
                    _ => format!("`{id}.{}`", keys[..depth - 1].join(".")),
                };
                let shown = here
                    .as_str()
                    .map(|v| format!(" (`{v}`)"))
                    .unwrap_or_default();
                return Err(bad(format!(
                    "{what} is {}{shown}, not a mapping, so `{}` cannot be set",
                    here.type_name(),
                    self.path
                )));
            };
            let at = match entries.iter().position(|e| e.0 == key) {
                Some(i) => i,
                None => {
                    entries.push((key.to_string(), loc, empty_map(loc)));
                    entries.len() - 1
                }
            };
            let slot = &mut entries[at].2;
            if depth == keys.len() {
                *slot = relocate(&self.value, loc);
                return Ok(id.clone());
            }
            // An empty value (`config:` with nothing after it) becomes a mapping.
            if matches!(slot, Node::Scalar { value, quoted: false, .. } if value.is_empty()) {
                *slot = empty_map(loc);
            }
            here = slot;
        }
        unreachable!("the loop returns at the last key")
    }
}

impl fmt::Display for Override {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.label())
    }
}

impl std::str::FromStr for Override {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        Self::parse(s)
    }
}

fn empty_map(loc: Loc) -> Node {
    Node::Map {
        entries: Vec::new(),
        loc,
    }
}

/// `node` with every location replaced by `loc`.
fn relocate(node: &Node, loc: Loc) -> Node {
    match node {
        Node::Scalar { value, quoted, .. } => Node::Scalar {
            value: value.clone(),
            quoted: *quoted,
            loc,
        },
        Node::Seq { items, .. } => Node::Seq {
            items: items.iter().map(|i| relocate(i, loc)).collect(),
            loc,
        },
        Node::Map { entries, .. } => Node::Map {
            entries: entries
                .iter()
                .map(|(k, _, v)| (k.clone(), loc, relocate(v, loc)))
                .collect(),
            loc,
        },
    }
}
