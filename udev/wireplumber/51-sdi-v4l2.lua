-- SDI: keep sdid's v4l2loopback nodes out of PipeWire (WirePlumber 0.4;
-- 0.5 reads wireplumber.conf.d/51-sdi-v4l2.conf instead).
--
-- PipeWire before 1.3.81 lists a v4l2loopback node as a camera but cannot
-- read it (v4l2loopback has no VIDIOC_EXPBUF, docs/loopback.md), so portal
-- clients (browsers, Flatpak apps, OBS, pipewiresrc) would pick "SDI camera"
-- and get no frame. sdid feeds the PipeWire camera process beside the
-- loopback nodes, whose "sdi-camera" node they read instead; V4L2 clients
-- (ffmpeg, OpenCV, v4l2src) open /dev/videoN directly and are not affected.
-- The devices are matched by card label (udev's ID_V4L_PRODUCT), the
-- labels of udev/modprobe.d/sdi-v4l2loopback.conf and sdid's defaults,
-- alone or followed by a camera's serial when sdid serves several ("SDI
-- camera sim-1"; "matches" takes a glob). A site with other labels
-- ([output] label, data_label) adds them here.
table.insert(v4l2_monitor.rules, {
  matches = {
    { { "device.product.name", "equals", "SDI camera" } },
    { { "device.product.name", "matches", "SDI camera *" } },
    { { "device.product.name", "equals", "SDI data" } },
    { { "device.product.name", "matches", "SDI data *" } },
  },
  apply_properties = {
    ["device.disabled"] = true,
  },
})
-- The same by the node's card, should a device slip through.
table.insert(v4l2_monitor.rules, {
  matches = {
    { { "api.v4l2.cap.card", "equals", "SDI camera" } },
    { { "api.v4l2.cap.card", "matches", "SDI camera *" } },
    { { "api.v4l2.cap.card", "equals", "SDI data" } },
    { { "api.v4l2.cap.card", "matches", "SDI data *" } },
  },
  apply_properties = {
    ["node.disabled"] = true,
  },
})
