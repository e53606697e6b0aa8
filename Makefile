# Installs SDI: binaries, systemd unit, udev rules, D-Bus policy and
# activation, v4l2loopback configuration, the control group, man pages and
# shell completions.
#
#   make                                  # cargo build --release
#   make install [DESTDIR=...] [PREFIX=/usr/local]
#   make uninstall [DESTDIR=...] [PREFIX=/usr/local]
#   make deb                              # Debian packages in target/debian/
#   make wheel                            # the Python module (python/) in target/wheels/
#
# With PREFIX=/usr the system-integration files go to the distribution's
# directories (/usr/lib/..., /usr/share/...); with any other prefix they go
# where the system reads administrator files (/etc/...) unless the prefix's
# own directory is one the consumer searches too (systemd units,
# sysusers.d, modules-load.d, D-Bus activation files).
# Without DESTDIR, install also reloads systemd, udev and creates the group.

PREFIX      ?= /usr/local
DESTDIR     ?=
CARGO       ?= cargo
INSTALL     ?= install
# CARGO_TARGET_DIR moves cargo's output, and with it what is installed.
TARGETDIR   ?= $(or $(CARGO_TARGET_DIR),target)/release

BINDIR      ?= $(PREFIX)/bin
# sdid looks for the PipeWire camera in ../libexec/sdi from its own directory.
CAMERADIR   ?= $(PREFIX)/libexec/sdi
DATADIR     ?= $(PREFIX)/share
MANDIR      ?= $(DATADIR)/man
SYSCONFDIR  ?= /etc
ifeq ($(PREFIX),/usr)
UDEVRULESDIR   ?= /usr/lib/udev/rules.d
DBUSPOLICYDIR  ?= /usr/share/dbus-1/system.d
MODPROBEDIR    ?= /usr/lib/modprobe.d
WIREPLUMBERDIR ?= /usr/share/wireplumber
else
UDEVRULESDIR   ?= $(SYSCONFDIR)/udev/rules.d
DBUSPOLICYDIR  ?= $(SYSCONFDIR)/dbus-1/system.d
MODPROBEDIR    ?= $(SYSCONFDIR)/modprobe.d
WIREPLUMBERDIR ?= $(SYSCONFDIR)/wireplumber
endif
UNITDIR        ?= $(PREFIX)/lib/systemd/system
USERUNITDIR    ?= $(PREFIX)/lib/systemd/user
SYSUSERSDIR    ?= $(PREFIX)/lib/sysusers.d
MODULESLOADDIR ?= $(PREFIX)/lib/modules-load.d
DBUSSERVICEDIR ?= $(DATADIR)/dbus-1/system-services
BASHCOMPDIR    ?= $(DATADIR)/bash-completion/completions
ZSHCOMPDIR     ?= $(DATADIR)/zsh/vendor-completions
FISHCOMPDIR    ?= $(DATADIR)/fish/vendor_completions.d

BINARIES = sdid sdictl
# Files with the install paths filled in; regenerated on every install so a
# changed PREFIX never leaves stale paths behind.
GENDIR    ?= target/dist
GENERATED = $(GENDIR)/sdid.service $(GENDIR)/sdid-user.service $(GENDIR)/org.sdi.Daemon.service

.PHONY: all build install uninstall clean-generated check-rules deb deb-package FORCE
all: build

# The PipeWire camera needs libpipewire-0.3-dev, libspa-0.2-dev, clang and
# libclang-dev; where they are missing sdid and sdictl still build.
build:
	$(CARGO) build --release -p sdi-daemon -p sdi-cli
	@$(CARGO) build --release -p sdi-pipewire-camera \
	  || echo "note: the PipeWire camera did not build (needs libpipewire-0.3-dev libspa-0.2-dev clang libclang-dev); sdid and sdictl did" >&2

$(GENDIR)/sdid.service: udev/systemd/sdid.service.in FORCE
	@mkdir -p $(GENDIR)
	sed 's|@bindir@|$(BINDIR)|g' $< > $@
$(GENDIR)/sdid-user.service: udev/systemd/sdid-user.service.in FORCE
	@mkdir -p $(GENDIR)
	sed 's|@bindir@|$(BINDIR)|g' $< > $@
$(GENDIR)/sdi-pipewire-camera.service: udev/systemd/sdi-pipewire-camera.service.in FORCE
	@mkdir -p $(GENDIR)
	sed 's|@cameradir@|$(CAMERADIR)|g' $< > $@
$(GENDIR)/org.sdi.Daemon.service: udev/dbus/org.sdi.Daemon.service.in FORCE
	@mkdir -p $(GENDIR)
	sed 's|@bindir@|$(BINDIR)|g' $< > $@

# The rules file is generated from udev/board-ids and checked in.
check-rules:
	udev/gen-rules.sh | cmp - udev/70-sdi-board.rules

install: $(GENERATED)
	@for b in $(BINARIES); do \
	  test -x $(TARGETDIR)/$$b || { echo "missing $(TARGETDIR)/$$b: run 'make' first" >&2; exit 1; }; \
	done
	$(INSTALL) -d $(DESTDIR)$(BINDIR)
	$(INSTALL) -m 0755 $(addprefix $(TARGETDIR)/,$(BINARIES)) $(DESTDIR)$(BINDIR)/
	@if [ -x $(TARGETDIR)/sdi-pipewire-camera ]; then \
	  echo "$(INSTALL) -D -m 0755 $(TARGETDIR)/sdi-pipewire-camera $(DESTDIR)$(CAMERADIR)/sdi-pipewire-camera"; \
	  $(INSTALL) -D -m 0755 $(TARGETDIR)/sdi-pipewire-camera $(DESTDIR)$(CAMERADIR)/sdi-pipewire-camera; \
	  $(MAKE) --no-print-directory install-camera-files; \
	fi
	$(INSTALL) -D -m 0644 $(GENDIR)/sdid.service $(DESTDIR)$(UNITDIR)/sdid.service
	$(INSTALL) -D -m 0644 $(GENDIR)/sdid-user.service $(DESTDIR)$(USERUNITDIR)/sdid.service
	$(INSTALL) -D -m 0644 udev/70-sdi-board.rules $(DESTDIR)$(UDEVRULESDIR)/70-sdi-board.rules
	$(INSTALL) -D -m 0644 udev/70-sdi-loopback.rules $(DESTDIR)$(UDEVRULESDIR)/70-sdi-loopback.rules
	$(INSTALL) -D -m 0644 udev/dbus/org.sdi.Daemon.conf $(DESTDIR)$(DBUSPOLICYDIR)/org.sdi.Daemon.conf
	$(INSTALL) -D -m 0644 $(GENDIR)/org.sdi.Daemon.service $(DESTDIR)$(DBUSSERVICEDIR)/org.sdi.Daemon.service
	$(INSTALL) -D -m 0644 udev/modprobe.d/sdi-v4l2loopback.conf $(DESTDIR)$(MODPROBEDIR)/sdi-v4l2loopback.conf
	$(INSTALL) -D -m 0644 udev/modules-load.d/sdi-v4l2loopback.conf $(DESTDIR)$(MODULESLOADDIR)/sdi-v4l2loopback.conf
	$(INSTALL) -D -m 0644 udev/sysusers.d/sdi.conf $(DESTDIR)$(SYSUSERSDIR)/sdi.conf
	$(INSTALL) -d -m 0755 $(DESTDIR)$(SYSCONFDIR)/sdi
	$(MAKE) --no-print-directory install-docs GENDIR=$(GENDIR) TARGETDIR=$(TARGETDIR)
ifeq ($(DESTDIR),)
	-systemd-sysusers $(SYSUSERSDIR)/sdi.conf
	-systemctl daemon-reload
	-udevadm control --reload
endif

# What comes with the PipeWire camera: WirePlumber's rule keeping the
# loopback nodes out of PipeWire (0.4 Lua, 0.5 SPA-JSON; docs/pipewire.md),
# which only helps where the camera process publishes instead, and the user
# unit that starts it with each user's PipeWire for the system service
# (enabled for every user by the .wants link).
.PHONY: install-camera-files
install-camera-files: $(GENDIR)/sdi-pipewire-camera.service
	$(INSTALL) -D -m 0644 $(GENDIR)/sdi-pipewire-camera.service $(DESTDIR)$(USERUNITDIR)/sdi-pipewire-camera.service
	$(INSTALL) -d $(DESTDIR)$(USERUNITDIR)/pipewire.service.wants
	ln -sf ../sdi-pipewire-camera.service $(DESTDIR)$(USERUNITDIR)/pipewire.service.wants/sdi-pipewire-camera.service
	$(INSTALL) -D -m 0644 udev/wireplumber/51-sdi-v4l2.lua $(DESTDIR)$(WIREPLUMBERDIR)/main.lua.d/51-sdi-v4l2.lua
	$(INSTALL) -D -m 0644 udev/wireplumber/51-sdi-v4l2.conf $(DESTDIR)$(WIREPLUMBERDIR)/wireplumber.conf.d/51-sdi-v4l2.conf

# Man page and shell completions, generated by sdictl from its clap
# definitions (skipped, with a note, if this sdictl cannot generate them).
.PHONY: install-docs
install-docs:
	@mkdir -p $(GENDIR)
	@if $(TARGETDIR)/sdictl man > $(GENDIR)/sdictl.1 2>/dev/null && test -s $(GENDIR)/sdictl.1; then \
	  $(INSTALL) -D -m 0644 $(GENDIR)/sdictl.1 $(DESTDIR)$(MANDIR)/man1/sdictl.1; \
	else echo "note: no man page from $(TARGETDIR)/sdictl" >&2; fi
	@for sh in bash zsh fish; do \
	  $(TARGETDIR)/sdictl completions $$sh > $(GENDIR)/sdictl.$$sh 2>/dev/null && test -s $(GENDIR)/sdictl.$$sh \
	    || { echo "note: no $$sh completions from $(TARGETDIR)/sdictl" >&2; continue; }; \
	  case $$sh in \
	    bash) dest=$(DESTDIR)$(BASHCOMPDIR)/sdictl ;; \
	    zsh)  dest=$(DESTDIR)$(ZSHCOMPDIR)/_sdictl ;; \
	    fish) dest=$(DESTDIR)$(FISHCOMPDIR)/sdictl.fish ;; \
	  esac; \
	  $(INSTALL) -D -m 0644 $(GENDIR)/sdictl.$$sh $$dest; \
	done

uninstall:
	rm -f $(addprefix $(DESTDIR)$(BINDIR)/,$(BINARIES))
	rm -f $(DESTDIR)$(CAMERADIR)/sdi-pipewire-camera
	-rmdir $(DESTDIR)$(CAMERADIR) 2>/dev/null
	rm -f $(DESTDIR)$(WIREPLUMBERDIR)/main.lua.d/51-sdi-v4l2.lua $(DESTDIR)$(WIREPLUMBERDIR)/wireplumber.conf.d/51-sdi-v4l2.conf
	rm -f $(DESTDIR)$(USERUNITDIR)/pipewire.service.wants/sdi-pipewire-camera.service $(DESTDIR)$(USERUNITDIR)/sdi-pipewire-camera.service
	-rmdir $(DESTDIR)$(USERUNITDIR)/pipewire.service.wants 2>/dev/null
	rm -f $(DESTDIR)$(UNITDIR)/sdid.service $(DESTDIR)$(USERUNITDIR)/sdid.service
	rm -f $(DESTDIR)$(UDEVRULESDIR)/70-sdi-board.rules $(DESTDIR)$(UDEVRULESDIR)/70-sdi-loopback.rules
	rm -f $(DESTDIR)$(DBUSPOLICYDIR)/org.sdi.Daemon.conf
	rm -f $(DESTDIR)$(DBUSSERVICEDIR)/org.sdi.Daemon.service
	rm -f $(DESTDIR)$(MODPROBEDIR)/sdi-v4l2loopback.conf
	rm -f $(DESTDIR)$(MODULESLOADDIR)/sdi-v4l2loopback.conf
	rm -f $(DESTDIR)$(SYSUSERSDIR)/sdi.conf
	rm -f $(DESTDIR)$(MANDIR)/man1/sdictl.1 $(DESTDIR)$(MANDIR)/man8/sdid.8
	rm -f $(DESTDIR)$(BASHCOMPDIR)/sdictl $(DESTDIR)$(ZSHCOMPDIR)/_sdictl $(DESTDIR)$(FISHCOMPDIR)/sdictl.fish
	-rmdir $(DESTDIR)$(SYSCONFDIR)/sdi 2>/dev/null
ifeq ($(DESTDIR),)
	-systemctl daemon-reload
	-udevadm control --reload
endif

clean-generated:
	rm -rf $(GENDIR)

# Debian packages (docs/install.md): `make deb` builds the release binaries
# (and the PipeWire camera when its crate builds here) and packages them;
# `make deb-package` only packages what TARGETDIR holds. The packages are
# dpkg-deb over a `make install DESTDIR=...` tree, see packaging/debian/mkdeb.sh
# for why not cargo-deb.
DEBDIR ?= target/debian

deb: build
	$(MAKE) --no-print-directory deb-package

deb-package:
	MAKE="$(MAKE)" packaging/debian/mkdeb.sh $(TARGETDIR) $(DEBDIR)

# The Python module (python/, docs/python.md): one abi3 wheel, built by
# maturin (from PyPI, in a venv: `pip install maturin`) from the workspace.
MATURIN  ?= maturin
WHEELDIR ?= $(abspath $(or $(CARGO_TARGET_DIR),target)/wheels)

.PHONY: wheel
wheel:
	cd python && $(MATURIN) build --release -o $(WHEELDIR)
