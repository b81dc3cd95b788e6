# Install rules for everything that is not a binary (binaries: install(TARGETS) beside each
# add_executable). The layout is the Debian package's (debian/*.install); with
# CMAKE_INSTALL_PREFIX=/usr, `cmake --install` gives the same files:
#
#   /usr/sbin/nccompd, /usr/bin/nccomp, modbus_map     (nccomp)
#   /usr/bin/ncsim, ncsim_peer, modbus_nc, can_nc      (nccomp-sim)
#   /lib/systemd/system/nccompd.service, /usr/lib/sysusers.d/nccompd.conf,
#   /usr/lib/tmpfiles.d/nccompd.conf (group and mode of /etc/nccompd: readable by the service)
#   /usr/bin/nccomp-page, /lib/systemd/system/nccomp-page.service,
#   /usr/lib/sysusers.d/nccomp-page.conf (the operator page, docs/operator-page.md),
#   /lib/systemd/system/nccomp-publish.service, /usr/lib/sysusers.d/nccomp-publish.conf,
#   /usr/lib/tmpfiles.d/nccomp-publish.conf, /etc/nccomp/nccomp-publish.toml (the MQTT
#   publisher, docs/mqtt.md)
#   /usr/bin/nccomp-analyzed, /lib/systemd/system/nccomp-analyzed.service,
#   /usr/lib/sysusers.d/nccomp-analyzed.conf, /etc/nccompd/nccomp-analyzed.toml (the continuous
#   analysis, docs/analyzed.md)
#   /etc/nccompd/nccompd.toml, reference-nc-modbus.toml
#   /usr/share/doc/nccomp/*.md, examples/*.toml; /usr/share/man/man{1,5,8}
#   /usr/share/bash-completion/completions/nccomp
#   /usr/share/nccomp-sim/config/ (ncsim.toml and the maps it includes)

# systemd's directories: where this systemd looks (pkg-config), below the prefix otherwise (a
# prefix other than /usr is a trial install: the unit's ExecStart= names /usr/sbin/nccompd).
set(_unitdir "${CMAKE_INSTALL_PREFIX}/lib/systemd/system")
set(_sysusersdir "${CMAKE_INSTALL_PREFIX}/lib/sysusers.d")
set(_tmpfilesdir "${CMAKE_INSTALL_PREFIX}/lib/tmpfiles.d")
if(CMAKE_INSTALL_PREFIX STREQUAL "/usr")
  pkg_get_variable(_pc_unitdir systemd systemdsystemunitdir)
  pkg_get_variable(_pc_sysusersdir systemd sysusersdir)
  pkg_get_variable(_pc_tmpfilesdir systemd tmpfilesdir)
  foreach(v unitdir sysusersdir tmpfilesdir)
    if(_pc_${v})
      set(_${v} "${_pc_${v}}")
    endif()
  endforeach()
endif()
set(NCCOMP_SYSTEMD_UNITDIR "${_unitdir}" CACHE PATH "Directory of the systemd unit")
set(NCCOMP_SYSUSERSDIR "${_sysusersdir}" CACHE PATH "Directory of the sysusers.d entry")
set(NCCOMP_TMPFILESDIR "${_tmpfilesdir}" CACHE PATH "Directory of the tmpfiles.d entry")

install(FILES systemd/nccompd.service DESTINATION "${NCCOMP_SYSTEMD_UNITDIR}")
install(FILES systemd/nccompd.sysusers.conf DESTINATION "${NCCOMP_SYSUSERSDIR}" RENAME nccompd.conf)
install(FILES systemd/nccompd.tmpfiles.conf DESTINATION "${NCCOMP_TMPFILESDIR}" RENAME nccompd.conf)
install(FILES systemd/nccomp-page.service DESTINATION "${NCCOMP_SYSTEMD_UNITDIR}")
install(FILES systemd/nccomp-page.sysusers.conf DESTINATION "${NCCOMP_SYSUSERSDIR}"
        RENAME nccomp-page.conf)
install(FILES systemd/nccomp-publish.service DESTINATION "${NCCOMP_SYSTEMD_UNITDIR}")
install(FILES systemd/nccomp-publish.sysusers.conf DESTINATION "${NCCOMP_SYSUSERSDIR}"
        RENAME nccomp-publish.conf)
install(FILES systemd/nccomp-publish.tmpfiles.conf DESTINATION "${NCCOMP_TMPFILESDIR}"
        RENAME nccomp-publish.conf)
install(FILES systemd/nccomp-analyzed.service DESTINATION "${NCCOMP_SYSTEMD_UNITDIR}")
install(FILES systemd/nccomp-analyzed.sysusers.conf DESTINATION "${NCCOMP_SYSUSERSDIR}"
        RENAME nccomp-analyzed.conf)

# The operator's configuration (conffiles in the package). Readable by the service through
# tmpfiles.d (root:nccomp 0640), applied after the user exists: systemd-tmpfiles --create.
# nccomp-analyzed's lives beside them: its user is in group nccomp.
install(FILES config/nccompd.toml config/reference-nc-modbus.toml config/nccomp-analyzed.toml
        DESTINATION "${CMAKE_INSTALL_FULL_SYSCONFDIR}/nccompd")
# The MQTT publisher's (nccomp-publish.service): root:nccomp-publish 0640 through its tmpfiles.d.
install(FILES config/nccomp-publish.toml DESTINATION "${CMAKE_INSTALL_FULL_SYSCONFDIR}/nccomp")

install(FILES README.md docs/calibration.md docs/can.md docs/checkpoints.md
              docs/closing-the-loop.md docs/config.md docs/creep.md docs/daemon.md docs/grinding.md
              docs/modbus.md docs/report.md docs/operator-page.md docs/mqtt.md
              docs/estimation.md docs/analyzed.md
        DESTINATION "${CMAKE_INSTALL_DOCDIR}")
install(FILES docs/images/operator-page-alarm.png docs/images/operator-page-report.png
        DESTINATION "${CMAKE_INSTALL_DOCDIR}/images")
install(FILES config/nccompd.toml config/nccompd-loopback.toml config/reference-nc-modbus.toml
              config/reference-nc-can.toml config/reference-nc-can-fd.toml
              config/nccomp-publish.toml config/nccomp-analyzed.toml
        DESTINATION "${CMAKE_INSTALL_DOCDIR}/examples")
# The drop-in for [can] restart = "daemon" (docs/can.md): an example, never active by itself.
install(FILES systemd/nccompd-can-restart.conf DESTINATION "${CMAKE_INSTALL_DOCDIR}/examples")
install(FILES LICENSE DESTINATION "${CMAKE_INSTALL_DOCDIR}")
install(FILES tools/nccomp/nccomp.bash DESTINATION
        "${CMAKE_INSTALL_DATADIR}/bash-completion/completions" RENAME nccomp)

# ncsim's example configuration with the files it names by relative path (the maps beside it,
# ../sim/ncsim/config/side_wall_checkpoints.toml), so `ncsim --config
# /usr/share/nccomp-sim/config/ncsim.toml` runs as docs/ncsim.md shows.
install(FILES config/ncsim.toml config/reference-nc-modbus.toml config/reference-nc-can.toml
        DESTINATION "${CMAKE_INSTALL_DATADIR}/nccomp-sim/config")
install(FILES sim/ncsim/config/side_wall_checkpoints.toml
              sim/ncsim/config/side_wall_checkpoints_can.toml
        DESTINATION "${CMAKE_INSTALL_DATADIR}/nccomp-sim/sim/ncsim/config")
install(FILES docs/ncsim.md DESTINATION "${CMAKE_INSTALL_DATADIR}/doc/nccomp-sim")
