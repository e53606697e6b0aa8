//! Helpers the D-Bus test modules share (not tests themselves).

use sdi_api::Camera1Proxy;
use sdi_tests::dbus::Bus;

/// A new connection to `bus` and the camera's typed proxy on it.
pub(crate) async fn camera(bus: &Bus) -> (zbus::Connection, Camera1Proxy<'static>) {
    let conn = bus.connect().await;
    let cam = Camera1Proxy::new(&conn).await.expect("camera proxy");
    (conn, cam)
}
