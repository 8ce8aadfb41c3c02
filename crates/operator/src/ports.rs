//! Typed ports and operator descriptors: the ports, types and config check of an operator, which
//! the dataflow validator knows independently of whether the operator is implemented yet.

use activemap_schemas::MessageKind;

/// One typed port of an operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PortSpec {
    /// Port name as written in dataflow files.
    pub name: &'static str,
    /// Message kind the port carries.
    pub kind: MessageKind,
}

/// Declares an operator's ports once, inside a module of their own (`inputs`, `outputs`): a
/// `pub const NAME: &str` per port, for dispatch (`match input.port { inputs::RGBD => … }`,
/// `ctx.send(outputs::GRID, …)`), and `ALL`, the [`PortSpec`] list its [`OperatorDescriptor`]
/// registers. A port misspelt where it is used is then a compile error, not a message that never
/// arrives; [`OperatorDescriptor::check_ports`] refuses a list that names a port twice.
///
/// ```
/// mod inputs {
///     activemap_operator::ports! { RGBD = "rgbd": activemap_schemas::MessageKind::RgbdFrame }
/// }
/// assert_eq!(inputs::ALL[0].name, inputs::RGBD);
/// ```
#[macro_export]
macro_rules! ports {
    ($($id:ident = $name:literal : $kind:expr),* $(,)?) => {
        $(
            #[doc = concat!("Port `", $name, "`.")]
            pub const $id: &str = $name;
        )*
        /// Every port, in declaration order, for the operator's descriptor.
        pub const ALL: &[$crate::PortSpec] = &[$($crate::PortSpec { name: $id, kind: $kind }),*];
    };
}

/// Checks an operator's `config:` value; returns a message naming the bad field.
pub type ConfigCheck = fn(&serde_json::Value) -> Result<(), String>;

/// What the validator knows about a built-in operator.
#[derive(Debug, Clone, Copy)]
pub struct OperatorDescriptor {
    /// Name used in `operator:`.
    pub name: &'static str,
    /// One line: what the operator does.
    pub summary: &'static str,
    /// Input ports.
    pub inputs: &'static [PortSpec],
    /// Output ports.
    pub outputs: &'static [PortSpec],
    /// True for evaluation operators, the only ones allowed to read ground truth.
    pub evaluation: bool,
    /// Config check (usually: deserialise into the operator's config struct).
    pub check_config: ConfigCheck,
}

impl OperatorDescriptor {
    /// Input port named `name`.
    pub fn input(&self, name: &str) -> Option<&PortSpec> {
        self.inputs.iter().find(|p| p.name == name)
    }

    /// Output port named `name`.
    pub fn output(&self, name: &str) -> Option<&PortSpec> {
        self.outputs.iter().find(|p| p.name == name)
    }

    /// Refuses a descriptor that names an input or an output port twice (or an empty name),
    /// naming the operator: dispatch by name could not tell the two apart.
    pub fn check_ports(&self) -> Result<(), String> {
        for (what, ports) in [("input", self.inputs), ("output", self.outputs)] {
            for (i, p) in ports.iter().enumerate() {
                if p.name.is_empty() {
                    return Err(format!(
                        "operator `{}`: an {what} port has no name",
                        self.name
                    ));
                }
                if ports[..i].iter().any(|q| q.name == p.name) {
                    return Err(format!(
                        "operator `{}`: {what} port `{}` is declared twice",
                        self.name, p.name
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Config check for operators whose config deserialises into `C` (use with `#[serde(deny_unknown_fields)]`).
pub fn check_config_as<C: serde::de::DeserializeOwned>(
    value: &serde_json::Value,
) -> Result<(), String> {
    config_from_value::<C>(value).map(|_| ())
}

/// Deserialise a node's config; `null` (no `config:` key) deserialises from an empty mapping so
/// configs with all-default fields need not be written.
pub fn config_from_value<C: serde::de::DeserializeOwned>(
    value: &serde_json::Value,
) -> Result<C, String> {
    let value = if value.is_null() {
        serde_json::Value::Object(Default::default())
    } else {
        value.clone()
    };
    serde_json::from_value(value).map_err(|e| e.to_string())
}
