'use strict';
// plotly.js's core (with scatter) and the trace types rigcal's pages draw: keep in step with
// BUNDLE_TRACES in src/rigcal/report/page.py
var Plotly = require('plotly.js/lib/core');

Plotly.register([
    require('plotly.js/lib/bar'),
    require('plotly.js/lib/scatter3d'),
    require('plotly.js/lib/mesh3d'),
]);

module.exports = Plotly;
