//! A YAML document as a tree whose every node remembers its line and column, so validation errors can
//! point at the offending token (`file:line:column`). Built from yaml-rust2's marked event stream.

use std::fmt;

use yaml_rust2::parser::{Event, MarkedEventReceiver, Parser};
use yaml_rust2::scanner::{Marker, TScalarStyle};

/// A 1-based line and column in the source file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, PartialOrd, Ord)]
pub struct Loc {
    /// Line, 1-based.
    pub line: usize,
    /// Column, 1-based.
    pub col: usize,
}

impl fmt::Display for Loc {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.line, self.col)
    }
}

impl Loc {
    fn from_marker(m: &Marker) -> Self {
        // yaml-rust2 reports 1-based lines and 0-based columns.
        Self {
            line: m.line(),
            col: m.col() + 1,
        }
    }
}

/// A YAML node with its location.
#[derive(Debug, Clone, PartialEq)]
pub enum Node {
    /// A scalar; `quoted` distinguishes `"1"` (string) from `1` (number).
    Scalar {
        /// Raw text.
        value: String,
        /// True for quoted or block scalars (always strings).
        quoted: bool,
        /// Where it starts.
        loc: Loc,
    },
    /// A sequence.
    Seq {
        /// Items.
        items: Vec<Node>,
        /// Where it starts.
        loc: Loc,
    },
    /// A mapping with scalar keys, in file order.
    Map {
        /// (key, key location, value).
        entries: Vec<(String, Loc, Node)>,
        /// Where it starts.
        loc: Loc,
    },
}

/// A YAML syntax or structure error with its location.
#[derive(Debug, Clone, PartialEq)]
pub struct YamlError {
    /// Where.
    pub loc: Loc,
    /// What.
    pub message: String,
}

impl Node {
    /// Location of the node's first token.
    pub fn loc(&self) -> Loc {
        match self {
            Node::Scalar { loc, .. } | Node::Seq { loc, .. } | Node::Map { loc, .. } => *loc,
        }
    }

    /// The scalar text, if a scalar.
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Node::Scalar { value, .. } => Some(value),
            _ => None,
        }
    }

    /// Value of key `key` in a mapping.
    pub fn get(&self, key: &str) -> Option<&Node> {
        match self {
            Node::Map { entries, .. } => entries.iter().find(|(k, _, _)| k == key).map(|e| &e.2),
            _ => None,
        }
    }

    /// Short name of the node's type, for error messages.
    pub fn type_name(&self) -> &'static str {
        match self {
            Node::Scalar { .. } => "a scalar",
            Node::Seq { .. } => "a sequence",
            Node::Map { .. } => "a mapping",
        }
    }

    /// Convert to JSON with YAML 1.2 core-schema scalar resolution (null, booleans, numbers).
    pub fn to_json(&self) -> serde_json::Value {
        use serde_json::Value;
        match self {
            Node::Scalar { value, quoted, .. } => {
                if *quoted {
                    return Value::String(value.clone());
                }
                match value.as_str() {
                    "" | "~" | "null" | "Null" | "NULL" => Value::Null,
                    "true" | "True" | "TRUE" => Value::Bool(true),
                    "false" | "False" | "FALSE" => Value::Bool(false),
                    v => {
                        if let Ok(i) = v.parse::<i64>() {
                            Value::from(i)
                        } else if let Some(f) = v
                            .parse::<f64>()
                            .ok()
                            .filter(|f| f.is_finite())
                            .and_then(serde_json::Number::from_f64)
                        {
                            Value::Number(f)
                        } else {
                            Value::String(v.to_string())
                        }
                    }
                }
            }
            Node::Seq { items, .. } => Value::Array(items.iter().map(Node::to_json).collect()),
            Node::Map { entries, .. } => Value::Object(
                entries
                    .iter()
                    .map(|(k, _, v)| (k.clone(), v.to_json()))
                    .collect(),
            ),
        }
    }
}

enum Frame {
    Seq(Vec<Node>, Loc),
    Map(Vec<(String, Loc, Node)>, Option<(String, Loc)>, Loc),
}

#[derive(Default)]
struct Builder {
    stack: Vec<Frame>,
    root: Option<Node>,
    error: Option<YamlError>,
    documents: usize,
}

impl Builder {
    fn push_value(&mut self, node: Node) {
        match self.stack.last_mut() {
            None => {
                if self.root.is_none() {
                    self.root = Some(node);
                }
            }
            Some(Frame::Seq(items, _)) => items.push(node),
            Some(Frame::Map(entries, pending_key, _)) => match pending_key.take() {
                None => match node {
                    Node::Scalar { value, loc, .. } => {
                        if entries.iter().any(|(k, _, _)| *k == value) && self.error.is_none() {
                            self.error = Some(YamlError {
                                loc,
                                message: format!("duplicate key `{value}`"),
                            });
                        }
                        *pending_key = Some((value, loc));
                    }
                    other => {
                        if self.error.is_none() {
                            self.error = Some(YamlError {
                                loc: other.loc(),
                                message: "mapping keys must be scalars".into(),
                            });
                        }
                        *pending_key = Some((String::new(), other.loc()));
                    }
                },
                Some((key, key_loc)) => entries.push((key, key_loc, node)),
            },
        }
    }
}

impl MarkedEventReceiver for Builder {
    fn on_event(&mut self, ev: Event, mark: Marker) {
        let loc = Loc::from_marker(&mark);
        match ev {
            Event::DocumentStart => {
                self.documents += 1;
                if self.documents > 1 && self.error.is_none() {
                    self.error = Some(YamlError {
                        loc,
                        message: "only one YAML document is allowed".into(),
                    });
                }
            }
            Event::Alias(_) => {
                if self.error.is_none() {
                    self.error = Some(YamlError {
                        loc,
                        message: "YAML aliases are not supported in dataflow files".into(),
                    });
                }
                self.push_value(Node::Scalar {
                    value: String::new(),
                    quoted: false,
                    loc,
                });
            }
            Event::Scalar(value, style, _, _) => self.push_value(Node::Scalar {
                value,
                quoted: style != TScalarStyle::Plain,
                loc,
            }),
            Event::SequenceStart(..) => self.stack.push(Frame::Seq(Vec::new(), loc)),
            Event::MappingStart(..) => self.stack.push(Frame::Map(Vec::new(), None, loc)),
            Event::SequenceEnd | Event::MappingEnd => {
                let node = match self.stack.pop() {
                    Some(Frame::Seq(items, loc)) => Node::Seq { items, loc },
                    Some(Frame::Map(entries, _, loc)) => Node::Map { entries, loc },
                    None => return,
                };
                self.push_value(node);
            }
            Event::Nothing | Event::StreamStart | Event::StreamEnd | Event::DocumentEnd => {}
        }
    }
}

/// Parse one YAML document into a located tree. An empty document is an empty mapping.
pub fn parse(source: &str) -> Result<Node, YamlError> {
    let mut builder = Builder::default();
    let mut parser = Parser::new_from_str(source);
    parser.load(&mut builder, true).map_err(|e| YamlError {
        loc: Loc::from_marker(e.marker()),
        message: e.info().to_string(),
    })?;
    if let Some(e) = builder.error {
        return Err(e);
    }
    Ok(builder.root.unwrap_or(Node::Map {
        entries: Vec::new(),
        loc: Loc { line: 1, col: 1 },
    }))
}

/// Write `node` as block-style YAML text that [`parse`] reads back into the same tree (up to
/// locations, and quoting of scalars that are strings either way). Comments are not kept.
pub fn emit(node: &Node) -> String {
    let mut out = String::new();
    match node {
        Node::Map { entries, .. } if !entries.is_empty() => emit_map(entries, 0, false, &mut out),
        Node::Seq { items, .. } if !items.is_empty() => emit_seq(items, 0, &mut out),
        other => {
            out.push_str(&inline(other));
            out.push('\n');
        }
    }
    out
}

/// The same tree with every location reset and every string scalar marked quoted, so two trees
/// compare equal exactly when they mean the same document.
pub fn canonical(node: &Node) -> Node {
    let loc = Loc::default();
    match node {
        Node::Scalar { value, .. } => Node::Scalar {
            value: value.clone(),
            quoted: node.to_json().is_string(),
            loc,
        },
        Node::Seq { items, .. } => Node::Seq {
            items: items.iter().map(canonical).collect(),
            loc,
        },
        Node::Map { entries, .. } => Node::Map {
            entries: entries
                .iter()
                .map(|(k, _, v)| (k.clone(), loc, canonical(v)))
                .collect(),
            loc,
        },
    }
}

fn pad(indent: usize, out: &mut String) {
    out.extend(std::iter::repeat_n(' ', indent));
}

/// Mapping entries at `indent`; with `first_inline`, the first key goes where the cursor is
/// (after a sequence's `- `).
fn emit_map(entries: &[(String, Loc, Node)], indent: usize, first_inline: bool, out: &mut String) {
    for (i, (key, _, value)) in entries.iter().enumerate() {
        if i > 0 || !first_inline {
            pad(indent, out);
        }
        out.push_str(&emit_key(key));
        out.push(':');
        emit_value(value, indent + 2, out);
    }
}

fn emit_seq(items: &[Node], indent: usize, out: &mut String) {
    for item in items {
        pad(indent, out);
        out.push('-');
        match item {
            Node::Map { entries, .. } if !entries.is_empty() => {
                out.push(' ');
                emit_map(entries, indent + 2, true, out);
            }
            other => emit_value(other, indent + 2, out),
        }
    }
}

/// A value after `key:` or `-`: scalars and empty collections on the same line, the others on
/// the next lines at `indent`.
fn emit_value(node: &Node, indent: usize, out: &mut String) {
    match node {
        Node::Map { entries, .. } if !entries.is_empty() => {
            out.push('\n');
            emit_map(entries, indent, false, out);
        }
        Node::Seq { items, .. } if !items.is_empty() => {
            out.push('\n');
            emit_seq(items, indent, out);
        }
        other => {
            let text = inline(other);
            if !text.is_empty() {
                out.push(' ');
                out.push_str(&text);
            }
            out.push('\n');
        }
    }
}

fn quote(text: &str) -> String {
    serde_json::Value::String(text.to_string()).to_string()
}

fn emit_key(key: &str) -> String {
    let safe = key
        .chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphanumeric() || c == '_')
        && key
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || "_-./".contains(c));
    if safe { key.to_string() } else { quote(key) }
}

/// A scalar or an empty collection on one line. A plain scalar stays plain unless it could not
/// be read back as such in block context, and then (being a string) is quoted.
fn inline(node: &Node) -> String {
    match node {
        Node::Seq { .. } => "[]".into(),
        Node::Map { .. } => "{}".into(),
        Node::Scalar { value, quoted, .. } => {
            if *quoted || (!plain_is_safe(value) && node.to_json().is_string()) {
                quote(value)
            } else {
                value.clone()
            }
        }
    }
}

fn plain_is_safe(value: &str) -> bool {
    let Some(first) = value.chars().next() else {
        return true;
    };
    let indicator_start = ",[]{}#&*!|>'\"%@`".contains(first)
        || (matches!(first, '-' | '?' | ':')
            && value[1..].chars().next().is_none_or(char::is_whitespace));
    !(indicator_start
        || value.contains(": ")
        || value.contains(" #")
        || value.ends_with(':')
        || value.contains(['\n', '\r', '\t'])
        || value.trim() != value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn locations_are_one_based_line_and_column() {
        let src = "a: 1\nb:\n  - x\n  - \"2\"\n";
        let root = parse(src).unwrap();
        let b = root.get("b").unwrap();
        let Node::Seq { items, .. } = b else {
            panic!("not a sequence")
        };
        assert_eq!(items[0].loc(), Loc { line: 3, col: 5 });
        assert_eq!(items[1].loc(), Loc { line: 4, col: 5 });
        assert_eq!(root.get("a").unwrap().loc(), Loc { line: 1, col: 4 });
        assert_eq!(root.to_json(), serde_json::json!({"a": 1, "b": ["x", "2"]}));
    }

    #[test]
    fn syntax_errors_and_duplicate_keys_have_locations() {
        let e = parse("a: [1, 2\nb: 3\n").unwrap_err();
        assert!(e.loc.line >= 2, "{e:?}");
        let e = parse("a: 1\na: 2\n").unwrap_err();
        assert_eq!(e.loc, Loc { line: 2, col: 1 });
        assert!(e.message.contains("duplicate key `a`"));
    }

    #[test]
    fn emitted_text_reads_back_as_the_same_tree() {
        let src = "# c\nnodes:\n  - id: sim\n    config: { scene: \"house:7\", width: 160, list: [1, [2, 3], {a: b}], e: {}, f: [], n: , s: 'a: b', t: \"x\\ny\" }\n  - id: x\n    \"odd key\": |\n      two\n      lines\n    weird: '- no'\n";
        let tree = parse(src).unwrap();
        let text = emit(&tree);
        let back = parse(&text).unwrap_or_else(|e| panic!("{e:?}\n{text}"));
        assert_eq!(canonical(&back), canonical(&tree), "{text}");
        assert!(
            text.starts_with(
                "nodes:\n  - id: sim\n    config:\n      scene: \"house:7\"\n      width: 160\n"
            ),
            "{text}"
        );
        assert_eq!(emit(&parse("").unwrap()), "{}\n");
    }
}
