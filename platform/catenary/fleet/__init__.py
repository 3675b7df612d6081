"""What crosses machines: push and pull between vehicles and the central side
(``catenary.fleet.transfer``), and the fleet's data for analysts (``catenary.fleet.analysts``)."""
