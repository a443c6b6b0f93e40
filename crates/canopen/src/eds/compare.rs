//! Comparing two dictionaries of the same product: ours, written from the
//! manual, against the vendor's EDS. What a device shows on the bus (types,
//! access, defaults) must agree; names may differ in case and separators.

use std::fmt;

use crate::NodeId;
use crate::od::{ObjectDictionary, SubObject, names_match};

/// One disagreement about one sub-object.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Difference {
    pub index: u16,
    pub sub: u8,
    /// `missing`, `name`, `data_type`, `access` or `default`.
    pub what: &'static str,
    pub ours: String,
    pub theirs: String,
}

impl fmt::Display for Difference {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "0x{:04X} sub {}: {} differs: ours {:?}, theirs {:?}",
            self.index, self.sub, self.what, self.ours, self.theirs
        )
    }
}

/// Every sub-object of `ours` checked against `theirs`: present, same name
/// (as [`names_match`] compares), same data type, same access, and the same
/// default value once both are read as their type for `node` (so `0x10` and
/// `16`, or `$NODEID+0x180` and `$NODEID+384`, agree).
pub fn compare(
    ours: &ObjectDictionary,
    theirs: &ObjectDictionary,
    node: NodeId,
) -> Vec<Difference> {
    let mut differences = Vec::new();
    for object in ours.objects.values() {
        for sub in object.subs.values() {
            let difference = |what, ours: String, theirs: String| Difference {
                index: object.index,
                sub: sub.sub_index,
                what,
                ours,
                theirs,
            };
            let Some(their) = theirs.sub(object.index, sub.sub_index) else {
                differences.push(difference("missing", sub.name.clone(), String::new()));
                continue;
            };
            if !names_match(&sub.name, &their.name) {
                differences.push(difference("name", sub.name.clone(), their.name.clone()));
            }
            if sub.data_type != their.data_type {
                differences.push(difference(
                    "data_type",
                    sub.data_type.to_string(),
                    their.data_type.to_string(),
                ));
            }
            if sub.access != their.access {
                differences.push(difference(
                    "access",
                    sub.access.to_string(),
                    their.access.to_string(),
                ));
            }
            if default_of(sub, node) != default_of(their, node) {
                differences.push(difference(
                    "default",
                    sub.default.clone().unwrap_or_default(),
                    their.default.clone().unwrap_or_default(),
                ));
            }
        }
    }
    differences
}

/// A default as the value it means, or its text when it reads as none.
fn default_of(sub: &SubObject, node: NodeId) -> String {
    match sub.default_value(Some(node)) {
        Ok(Some(value)) => value.to_text(),
        Ok(None) => String::new(),
        Err(_) => sub.default.clone().unwrap_or_default(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::od::{AccessType, DataType, Object};

    fn dictionary(
        name: &str,
        data_type: DataType,
        access: AccessType,
        default: &str,
    ) -> ObjectDictionary {
        let mut sub = SubObject::new(0, name, data_type, access);
        sub.default = Some(default.into());
        let mut dictionary = ObjectDictionary::new();
        dictionary.insert(Object::var(0x1800, sub));
        dictionary
    }

    #[test]
    fn equal_meaning_in_other_spelling_agrees() {
        let node = NodeId::new(3).unwrap();
        let ours = dictionary(
            "COB_ID used by TPDO",
            DataType::Unsigned32,
            AccessType::Rw,
            "$NODEID+0x180",
        );
        let theirs = dictionary(
            "COB-ID used by TPDO",
            DataType::Unsigned32,
            AccessType::Rw,
            "$NODEID+384",
        );
        assert_eq!(compare(&ours, &theirs, node), vec![]);
    }

    #[test]
    fn every_kind_of_disagreement_is_reported() {
        let node = NodeId::new(3).unwrap();
        let ours = dictionary("Mode", DataType::Integer8, AccessType::Rw, "1");
        let theirs = dictionary("Other", DataType::Unsigned8, AccessType::Ro, "2");
        let whats: Vec<_> = compare(&ours, &theirs, node)
            .iter()
            .map(|d| d.what)
            .collect();
        assert_eq!(whats, vec!["name", "data_type", "access", "default"]);
        let empty = ObjectDictionary::new();
        let missing = compare(&ours, &empty, node);
        assert_eq!(missing.len(), 1);
        assert_eq!(
            missing[0].to_string(),
            "0x1800 sub 0: missing differs: ours \"Mode\", theirs \"\""
        );
    }
}
