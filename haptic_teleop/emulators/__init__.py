"""Protocol-level device emulators: separate processes that speak a vendor's wire protocol on
127.0.0.1 sockets or pseudo-terminals, so the unmodified SDKs can be tested against them."""
