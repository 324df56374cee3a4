#pragma once
// Readiness for service managers: systemd's notify protocol (a datagram to $NOTIFY_SOCKET), so a
// `Type=notify` unit is "started" only once the stores are open and the ports listen, and sees
// reloads and the stop. Without NOTIFY_SOCKET (a shell, a container) nothing is sent.
#include <string>

namespace tessera::tools {

// Sends `state` ("READY=1", "RELOADING=1\nMONOTONIC_USEC=...", "STOPPING=1", "STATUS=...").
// Returns false only when NOTIFY_SOCKET is set and the datagram could not be sent.
bool notify_service_manager(const std::string& state);

// "MONOTONIC_USEC=<CLOCK_MONOTONIC in µs>", which systemd wants beside RELOADING=1.
std::string monotonic_usec_field();

}  // namespace tessera::tools
