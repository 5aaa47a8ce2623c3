// plotly.js's own esbuild settings (node_modules/plotly.js/esbuild-config.js), minified, on entry.js
'use strict';
const fs = require('fs');
const path = require('path');
const esbuild = require('esbuild');
const { environmentPlugin } = require('esbuild-plugin-environment');
const { glsl } = require('esbuild-plugin-glsl');
const InlineCSSPlugin = require('esbuild-plugin-inline-css');

const out = path.join(__dirname, '..', '..', 'src', 'rigcal', 'report', 'js', 'plotly-rigcal.min.js');
const version = JSON.parse(fs.readFileSync(require.resolve('plotly.js/package.json'), 'utf8')).version;
// the core has scatter; entry.js registers the others
const traces = ['scatter'].concat(Array.from(fs.readFileSync(path.join(__dirname, 'entry.js'), 'utf8')
    .matchAll(/require\('plotly\.js\/lib\/(\w+)'\)/g), m => m[1]).filter(t => t !== 'core'));
const banner = `/**
* plotly.js v${version} - partial bundle with the trace types ${traces.join(', ')}
* built by rigcal's tools/plotly-bundle from the npm package plotly.js@${version}
* Copyright 2012-2026, Plotly, Inc.
* All rights reserved.
* Licensed under the MIT license
*/`;

esbuild.build({
    entryPoints: [path.join(__dirname, 'entry.js')],
    outfile: out,
    format: 'iife',
    globalName: 'Plotly',
    bundle: true,
    minify: true,
    sourcemap: false,
    banner: { js: banner },
    plugins: [InlineCSSPlugin(), glsl({ minify: true }), environmentPlugin({ NODE_DEBUG: false })],
    alias: { regl: '@plotly/regl', stream: 'stream-browserify' },
    define: { global: 'window', 'define.amd': 'false' },
    target: 'es2016',
    logLevel: 'info',
}).catch(() => process.exit(1));
