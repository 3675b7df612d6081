"""What crosses machines, and the fleet's data for analysts (``catenary.fleet.analysts``)."""
