//! Descriptors of pipeline operators that are not built yet: their ports and types are fixed
//! here so a dataflow using them validates, and `activemap run` refuses to launch them with a
//! clear message. Every operator of SPEC §1 is built now (see the registry), so the list is
//! empty; a future operator starts here with its descriptor before its implementation exists.

use activemap_runtime::OperatorDescriptor;

use crate::Registered;

/// The planned descriptors (none at the moment).
pub fn descriptors() -> Vec<OperatorDescriptor> {
    Vec::new()
}

/// Registry entries (no implementation yet).
pub fn registered() -> Vec<Registered> {
    descriptors()
        .into_iter()
        .map(|descriptor| Registered {
            descriptor,
            implementation: None,
        })
        .collect()
}
