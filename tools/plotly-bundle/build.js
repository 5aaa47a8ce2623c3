// plotly.js's own esbuild settings (node_modules/plotly.js/esbuild-config.js), minified, on entry.js.
// Writes the bundle (default: src/rigcal/report/js/plotly-rigcal.min.js, or the path given as the
// first argument) and beside it <bundle>.LICENSE.txt: the license of every npm package whose code
// went into the bundle (from esbuild's list of inputs).
'use strict';
const fs = require('fs');
const path = require('path');
const esbuild = require('esbuild');
const { environmentPlugin } = require('esbuild-plugin-environment');
const { glsl } = require('esbuild-plugin-glsl');
const crypto = require('crypto');

const out = process.argv[2]
    ? path.resolve(process.argv[2])
    : path.join(__dirname, '..', '..', 'src', 'rigcal', 'report', 'js', 'plotly-rigcal.min.js');
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
* Licenses of the bundled packages: plotly-rigcal.min.js.LICENSE.txt
*/`;

// CSS files become a script that adds a <style> once (plotly.js's build does this with a plugin
// whose style id hashes the file's absolute path; here the id hashes the path relative to this
// folder, so that the bundle is the same wherever it is built)
const inlineCss = {
    name: 'rigcal-inline-css',
    setup(build) {
        build.onLoad({ filter: /\.css$/ }, args => {
            const id = crypto.createHash('sha256')
                .update(path.relative(__dirname, args.path).split(path.sep).join('/')).digest('hex');
            const css = fs.readFileSync(args.path, 'utf8');
            return {
                loader: 'js',
                contents: `(function(){if(!document.getElementById(${JSON.stringify(id)})){` +
                    `var e=document.createElement('style');e.id=${JSON.stringify(id)};` +
                    `e.textContent=${JSON.stringify(css)};document.head.appendChild(e);}})();`,
            };
        });
    },
};

// the package folder (node_modules/[@scope/]name) of an input file of the bundle, or null
function packageDir(input) {
    const parts = input.split('/');
    const i = parts.lastIndexOf('node_modules');
    if (i < 0) return null;
    const n = parts[i + 1] && parts[i + 1].startsWith('@') ? 2 : 1;
    return parts.slice(0, i + 1 + n).join('/');
}

function licenses(metafile) {
    const dirs = new Set();
    for (const input of Object.keys(metafile.inputs)) {
        const dir = packageDir(input);
        if (dir) dirs.add(dir);
    }
    const sections = [];
    for (const dir of Array.from(dirs).sort()) {
        const pkg = JSON.parse(fs.readFileSync(path.join(__dirname, dir, 'package.json'), 'utf8'));
        const file = fs.readdirSync(path.join(__dirname, dir)).sort()
            .find(f => /^licen[cs]e(\.(md|txt|markdown))?$/i.test(f));
        const text = file ? fs.readFileSync(path.join(__dirname, dir, file), 'utf8').trim()
            : `(no license file in the package; package.json says: ${JSON.stringify(pkg.license || null)})`;
        sections.push(`${pkg.name}@${pkg.version} (license: ${JSON.stringify(pkg.license || null)})\n\n${text}\n`);
    }
    return `Third-party software in plotly-rigcal.min.js (built by rigcal's tools/plotly-bundle):\n` +
        `${sections.length} npm packages, each with its license as shipped in the package.\n\n` +
        sections.join('\n' + '-'.repeat(78) + '\n\n');
}

esbuild.build({
    entryPoints: [path.join(__dirname, 'entry.js')],
    outfile: out,
    format: 'iife',
    globalName: 'Plotly',
    bundle: true,
    minify: true,
    sourcemap: false,
    metafile: true,
    banner: { js: banner },
    plugins: [inlineCss, glsl({ minify: true }), environmentPlugin({ NODE_DEBUG: false })],
    alias: { regl: '@plotly/regl', stream: 'stream-browserify' },
    define: { global: 'window', 'define.amd': 'false' },
    target: 'es2016',
    logLevel: 'info',
}).then(result => {
    fs.writeFileSync(out + '.LICENSE.txt', licenses(result.metafile));
}).catch(() => process.exit(1));
