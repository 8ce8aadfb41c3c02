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
}
