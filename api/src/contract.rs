//! A member of the interface as introspection describes it (name, kind,
//! signatures), built from the proxy's Rust types by
//! [`crate::proxy::members`] so a test can compare the proxy with what sdid
//! serves.

use zbus::zvariant::Signature;

/// What a member is, with the signatures introspection gives it.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub enum MemberKind {
    /// In and out signatures: each argument's, concatenated.
    Method { input: String, output: String },
    /// The type; every property of the interface is read-only.
    Property { signature: String },
    /// The arguments' signatures, concatenated.
    Signal { args: String },
}

/// One method, property or signal, named as on the bus.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub struct Member {
    pub name: String,
    pub kind: MemberKind,
}

impl Member {
    /// `rust_name` is the proxy's snake_case name; zbus names the member in
    /// PascalCase.
    pub fn method(rust_name: &str, args: &[&Signature], reply: &Signature) -> Self {
        Self {
            name: bus_name(rust_name),
            kind: MemberKind::Method {
                input: concat(args),
                output: body(reply),
            },
        }
    }

    pub fn property(rust_name: &str, signature: &Signature) -> Self {
        Self {
            name: bus_name(rust_name),
            kind: MemberKind::Property {
                signature: signature.to_string(),
            },
        }
    }

    pub fn signal(rust_name: &str, args: &[&Signature]) -> Self {
        Self {
            name: bus_name(rust_name),
            kind: MemberKind::Signal { args: concat(args) },
        }
    }
}

/// `set_exposure_us` -> `SetExposureUs`, as zbus derives member names; a
/// person's `exposure-us` or `ExposureUs` names the same member.
pub fn bus_name(rust_name: &str) -> String {
    rust_name
        .split(['_', '-'])
        .map(|word| {
            let mut chars = word.chars();
            chars
                .next()
                .map(|c| c.to_ascii_uppercase().to_string() + chars.as_str())
                .unwrap_or_default()
        })
        .collect()
}

fn concat(args: &[&Signature]) -> String {
    args.iter().map(|s| s.to_string()).collect()
}

/// A reply's signature as a message body: a tuple's fields are the body's
/// arguments (`(u64, u64)` is `tt`, not `(tt)`), `()` is no argument.
fn body(reply: &Signature) -> String {
    match reply {
        Signature::Structure(fields) => fields.iter().map(|s| s.to_string()).collect(),
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use zbus::zvariant::Type;

    #[test]
    fn names_and_bodies_as_on_the_bus() {
        let m = Member::method(
            "set_exposure_us",
            &[<f64 as Type>::SIGNATURE],
            <(u64, u64) as Type>::SIGNATURE,
        );
        assert_eq!(m.name, "SetExposureUs");
        assert_eq!(
            m.kind,
            MemberKind::Method {
                input: "d".into(),
                output: "tt".into()
            }
        );
        let unit = Member::method("stop", &[], <() as Type>::SIGNATURE);
        assert_eq!(
            unit.kind,
            MemberKind::Method {
                input: String::new(),
                output: String::new()
            }
        );
    }

    #[test]
    fn every_proxy_member_once() {
        let members = crate::proxy::members();
        let mut names: Vec<_> = members.iter().map(|m| m.name.as_str()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), members.len());
        assert!(names.contains(&"SnapshotToFd") && names.contains(&"Stats"));
    }
}
