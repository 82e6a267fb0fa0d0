/*
 * ui.js: the page around the canvas: the join form, the list of users
 * present (#users), the status line (#status), the errors in words
 * (#errors) and the toggles (#show-boxes, #show-collisions). It reads
 * and writes the DOM only; main.js decides what to show.
 */

/* Errors shown at once; older ones scroll out of the panel (all of them
 * stay in cvre.state().errors). */
const UI_ERRORS_SHOWN = 6;

const $ = (id) => document.getElementById(id);

/* Hooks up the form: on_join(name, password) when it is submitted. */
export function ui_new(on_join) {
    const ui = { errors: [], users_key: '' };
    $('join-form').addEventListener('submit', (e) => {
        e.preventDefault();
        on_join($('name').value.trim(), $('password').value);
    });
    return ui;
}

/* Shows the form (with name filled in) or hides it. */
export function ui_form(ui, show, name) {
    $('join-form').hidden = !show;
    $('join').disabled = !show;
    if (show && name !== undefined)
        $('name').value = name;
}

export function ui_status(ui, words) {
    $('status').textContent = words;
}

/* Adds an error, in words, to #errors. */
export function ui_error(ui, words) {
    ui.errors.push(words);
    const li = document.createElement('li');
    li.textContent = words;
    const list = $('errors');
    list.append(li);
    while (list.children.length > UI_ERRORS_SHOWN)
        list.firstElementChild.remove();
}

/* The users present: self first, marked, then the others by name. */
export function ui_users(ui, self_name, others) {
    const names = others.map((a) => a.name).sort((a, b) => a.localeCompare(b));
    const key = JSON.stringify([self_name, names]);
    if (key === ui.users_key)
        return;
    ui.users_key = key;
    const list = $('users');
    list.replaceChildren();
    if (self_name !== null) {
        const li = document.createElement('li');
        li.className = 'self';
        li.textContent = `${self_name} (you)`;
        list.append(li);
    }
    for (const n of names) {
        const li = document.createElement('li');
        li.textContent = n;
        list.append(li);
    }
    $('users-count').textContent = self_name === null ? '' : `(${1 + names.length})`;
}

export function ui_show_boxes() {
    return $('show-boxes').checked;
}

export function ui_show_collisions() {
    return $('show-collisions').checked;
}

/* The HUD line: where we are and the round trip. */
export function ui_hud(ui, words) {
    $('hud').textContent = words;
}
