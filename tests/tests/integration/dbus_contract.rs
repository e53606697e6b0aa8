//! The D-Bus contract checked both ways: what sdid serves and what its
//! clients call are the same interface.
//!
//! The served side is sdid's own introspection of `org.sdi.Camera1`, read
//! over a private bus and parsed with `zbus_xml`. The client side is
//! `sdi_api::proxy::members()`: it expands from the same declaration as
//! `Camera1Proxy` (one macro in `api/src/proxy.rs`), each signature taken
//! from the Rust type of each argument and reply (`zvariant::Type`), so it
//! is the proxy, not a second list of it. Every proxy member must be served
//! with the same signature (a client call that would fail), and every
//! served member must be in the proxy (a method sdictl and the tests cannot
//! reach). `tests/tests/integration/dbus_api.rs` compares the served introspection with
//! `daemon/dbus/org.sdi.Camera1.xml`, the interface's description for
//! other languages.

use std::collections::BTreeSet;

use sdi_api::contract::{Member, MemberKind};
use sdi_tests::dbus::{Bus, Daemon};
use sdi_tests::require_dbus;
use zbus_xml::{ArgDirection, Node, PropertyAccess};

/// The members of `org.sdi.Camera1` as sdid introspects them.
async fn served(address: &str) -> BTreeSet<Member> {
    let conn = zbus::connection::Builder::address(address)
        .expect("bus address")
        .build()
        .await
        .expect("connect to the test bus");
    let xml = zbus::fdo::IntrospectableProxy::builder(&conn)
        .destination(sdi_api::BUS_NAME)
        .expect("bus name")
        .path(sdi_api::OBJECT_PATH)
        .expect("object path")
        .build()
        .await
        .expect("introspectable proxy")
        .introspect()
        .await
        .expect("Introspect");
    let node = Node::from_reader(xml.as_bytes()).expect("introspection XML");
    let iface = node
        .interfaces()
        .iter()
        .find(|i| i.name().as_str() == sdi_api::INTERFACE)
        .expect("org.sdi.Camera1 served");
    let sig = |args: &[zbus_xml::Arg], dir: Option<ArgDirection>| -> String {
        args.iter()
            .filter(|a| dir.is_none() || a.direction() == dir)
            .map(|a| a.ty().to_string())
            .collect()
    };
    let methods = iface.methods().iter().map(|m| Member {
        name: m.name().to_string(),
        kind: MemberKind::Method {
            input: sig(m.args(), Some(ArgDirection::In)),
            output: sig(m.args(), Some(ArgDirection::Out)),
        },
    });
    let properties = iface.properties().iter().map(|p| {
        assert_eq!(
            p.access(),
            PropertyAccess::Read,
            "{}: every property is read-only; a setting changes through its Set method",
            p.name()
        );
        Member {
            name: p.name().to_string(),
            kind: MemberKind::Property {
                signature: p.ty().to_string(),
            },
        }
    });
    let signals = iface.signals().iter().map(|s| Member {
        name: s.name().to_string(),
        kind: MemberKind::Signal {
            args: sig(s.args(), None),
        },
    });
    methods.chain(properties).chain(signals).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_proxy_and_the_served_interface_agree_both_ways() {
    require_dbus!();
    let bus = Bus::start();
    let _d = Daemon::start(&bus, &[]);
    let served = served(&bus.address).await;
    let proxy: BTreeSet<Member> = sdi_api::proxy::members().into_iter().collect();
    let missing: Vec<_> = proxy.difference(&served).collect();
    let unreachable: Vec<_> = served.difference(&proxy).collect();
    assert!(
        missing.is_empty() && unreachable.is_empty(),
        "declared by Camera1Proxy but not served as declared (api/src/proxy.rs vs daemon/src/dbus/camera.rs):\n{missing:#?}\n\
         served but not in Camera1Proxy as served:\n{unreachable:#?}"
    );
}
