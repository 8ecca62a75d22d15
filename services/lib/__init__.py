"""Libraries the services share (archives, processes, wording, networks, point clouds); they
import no service, and the supervisor may use them directly."""
